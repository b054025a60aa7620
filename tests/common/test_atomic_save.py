"""Models are saved whole or not at all: a write that fails part-way (a full disk, an injected error) leaves the
previous model intact and no cut file under the model's name."""

from __future__ import annotations

import errno
import os
import shutil
import subprocess
import zipfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from sb3_ef import DrQv2EF
from sb3_ef.common.files import TEMPORARY_SUFFIX, atomic_path
from sb3_ef.common.saved_models import model_zip_path, save_model_atomically
from sb3_ef.common.validation import is_intact
from tests.test_bad_inputs import DRQV2_POLICY, drqv2_ef, sac_ef, tdmpc2_ef, toy_env


class AtomicDrQv2EF(DrQv2EF):
    """DrQv2EF with the ``save`` every sb3-ef class has through its host mixin."""

    def save(self, path: Any, exclude: Any = None, include: Any = None) -> None:
        save_model_atomically(super().save, path, exclude, include)


@pytest.fixture
def model() -> AtomicDrQv2EF:
    return AtomicDrQv2EF("CnnPolicy", toy_env(), buffer_size=100, policy_kwargs=dict(DRQV2_POLICY), device="cpu")


def disk_full_at(member: str) -> Any:
    """A ``ZipFile.writestr`` that raises ENOSPC when asked to write ``member`` (after the weights were written)."""
    original = zipfile.ZipFile.writestr

    def writestr(archive: zipfile.ZipFile, name: Any, *args: Any, **kwargs: Any) -> None:
        if getattr(name, "filename", name) == member:
            raise OSError(errno.ENOSPC, "No space left on device")
        original(archive, name, *args, **kwargs)

    return writestr


def leftovers(folder: Path) -> list[str]:
    return sorted(path.name for path in folder.iterdir() if TEMPORARY_SUFFIX in path.name)


def test_the_zip_suffix_rule_is_sb3s():
    assert model_zip_path("runs/model") == Path("runs/model.zip")
    assert model_zip_path("model.zip") == Path("model.zip")
    assert model_zip_path("model.pkl") == Path("model.pkl")


def test_a_save_that_fails_part_way_keeps_the_old_model(model, tmp_path, monkeypatch):
    model.save(tmp_path / "model")
    old = (tmp_path / "model.zip").read_bytes()
    model.num_timesteps = 123
    monkeypatch.setattr(zipfile.ZipFile, "writestr", disk_full_at("_stable_baselines3_version"))
    with pytest.raises(OSError, match="No space left"):
        model.save(tmp_path / "model")
    monkeypatch.undo()
    assert (tmp_path / "model.zip").read_bytes() == old
    assert leftovers(tmp_path) == []
    with pytest.raises(OSError, match="No space left"):  # a first save leaves nothing under the final name
        monkeypatch.setattr(zipfile.ZipFile, "writestr", disk_full_at("_stable_baselines3_version"))
        model.save(tmp_path / "second.zip")
    assert sorted(path.name for path in tmp_path.iterdir()) == ["model.zip"]


def test_an_interrupted_save_keeps_the_old_model(model, tmp_path, monkeypatch):
    model.save(tmp_path / "model.zip")
    old = (tmp_path / "model.zip").read_bytes()

    def interrupt(*args: Any, **kwargs: Any) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(zipfile.ZipFile, "writestr", interrupt)
    with pytest.raises(KeyboardInterrupt):
        model.save(tmp_path / "model.zip")
    assert (tmp_path / "model.zip").read_bytes() == old and leftovers(tmp_path) == []


def test_file_objects_are_written_directly(model, tmp_path):
    with open(tmp_path / "model.zip", "wb") as file:
        model.save(file)
    assert is_intact(tmp_path / "model.zip") and leftovers(tmp_path) == []


def test_a_folder_is_not_a_model_path(tmp_path):
    (tmp_path / "model.zip").mkdir()
    with pytest.raises(IsADirectoryError, match="it is a folder"):
        save_model_atomically(lambda *args: None, tmp_path / "model.zip")


def test_the_rename_is_flushed_with_its_folder(tmp_path, monkeypatch):
    flushed: list[int] = []
    original = os.fsync
    monkeypatch.setattr(os, "fsync", lambda descriptor: (flushed.append(descriptor), original(descriptor)))
    opened: list[str] = []
    original_open = os.open
    monkeypatch.setattr(os, "open", lambda path, *args: (opened.append(str(path)), original_open(path, *args))[1])
    with atomic_path(tmp_path / "file.txt") as temporary:
        temporary.write_text("whole")
    assert len(flushed) == 2 and opened == [str(tmp_path)]  # the file, then its folder
    assert (tmp_path / "file.txt").read_text() == "whole"


@pytest.fixture
def small_disk(tmp_path) -> Iterator[Path]:
    """A 2 MiB tmpfs (needs mount rights: root in a container that allows it)."""
    folder = tmp_path / "disk"
    folder.mkdir()
    if shutil.which("mount") is None or os.geteuid() != 0:
        pytest.skip("mounting a small tmpfs needs root")
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=2m", "tmpfs", str(folder)], capture_output=True)
    if mounted.returncode != 0:
        pytest.skip(f"this machine does not allow mounting a tmpfs: {mounted.stderr.decode().strip()}")
    try:
        yield folder
    finally:
        subprocess.run(["umount", "--lazy", str(folder)], check=True)


def test_a_disk_that_fills_during_the_save_keeps_the_old_model(model, small_disk):
    model.save(small_disk / "model.zip")
    old = (small_disk / "model.zip").read_bytes()
    free = os.statvfs(small_disk).f_bavail * os.statvfs(small_disk).f_frsize
    (small_disk / "filler").write_bytes(bytes(free - len(old) // 2))  # room for half a model
    with pytest.raises(OSError) as raised:
        model.save(small_disk / "model.zip")
    assert raised.value.errno == errno.ENOSPC
    assert (small_disk / "model.zip").read_bytes() == old and leftovers(small_disk) == []
    with pytest.raises(OSError):
        model.save(small_disk / "other.zip")
    assert not (small_disk / "other.zip").exists() and leftovers(small_disk) == []


@pytest.mark.parametrize("make", [drqv2_ef, sac_ef, tdmpc2_ef], ids=["DrQv2EF", "SACEF", "TDMPC2EF"])
def test_every_class_saves_atomically(make, tmp_path, monkeypatch):
    model = make()
    model.save(tmp_path / "model.zip")
    old = (tmp_path / "model.zip").read_bytes()
    monkeypatch.setattr(zipfile.ZipFile, "writestr", disk_full_at("_stable_baselines3_version"))
    with pytest.raises(OSError):
        model.save(tmp_path / "model.zip")
    assert (tmp_path / "model.zip").read_bytes() == old and leftovers(tmp_path) == []
