"""The package a user installs: the wheel holds every file of ``sb3_ef/`` (the zoo configs of ``zoo_configs/`` as
real files, the reference scores), and an installed copy, away from the source tree, finds its default configs and
reference data."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: What the build reads besides the package and the configs it links.
BUILD_FILES = ("pyproject.toml", "setup.cfg", "README.md", "LICENSE")

#: Run by the installed copy: where it was imported from, a default config and the rows of one reference.
_READ_INSTALLED = """
import json, sb3_ef
from sb3_ef.analysis.reference import load_reference
from sb3_ef.zoo.config import default_config_path
print(json.dumps([sb3_ef.__file__, default_config_path("drqv2").read_text(), len(load_reference("drqv2"))]))
"""


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``pip wheel --no-deps`` of a clean copy of the sources (no ``build/`` left from an earlier build)."""
    source = tmp_path_factory.mktemp("source")
    for name in BUILD_FILES:
        shutil.copy(ROOT / name, source)
    for folder in ("sb3_ef", "zoo_configs"):
        shutil.copytree(ROOT / folder, source / folder, symlinks=True, ignore=shutil.ignore_patterns("__pycache__"))
    out = tmp_path_factory.mktemp("wheel")
    command = [sys.executable, "-m", "pip", "wheel", str(source), "--no-deps", "--no-build-isolation", "-w", str(out)]
    result = subprocess.run(command, capture_output=True, text=True)
    assert result.returncode == 0, result.stdout[-2000:] + result.stderr[-2000:]
    (path,) = out.glob("sb3_ef-*.whl")
    return path


def test_the_wheel_holds_every_file_of_the_package_and_the_configs_as_files(wheel):
    package = {
        path.relative_to(ROOT).as_posix()
        for path in (ROOT / "sb3_ef").rglob("*")
        if path.is_file() and "__pycache__" not in path.parts
    }
    configs = {path.name: path.read_bytes() for path in (ROOT / "zoo_configs").glob("*.yml")}
    with zipfile.ZipFile(wheel) as archive:
        assert package - set(archive.namelist()) == set()
        shipped = {name: archive.read(f"sb3_ef/zoo/configs/{name}") for name in configs}
    assert "drqv2.yml" in configs and shipped == configs


def test_an_installed_copy_reads_its_configs_and_reference_scores_outside_the_sources(wheel, tmp_path):
    site = tmp_path / "site"
    with zipfile.ZipFile(wheel) as archive:
        archive.extractall(site)
    env = {**os.environ, "PYTHONPATH": str(site), "MUJOCO_GL": "egl"}
    command = [sys.executable, "-c", _READ_INSTALLED]
    result = subprocess.run(command, capture_output=True, text=True, cwd=tmp_path, env=env)
    assert result.returncode == 0, result.stderr[-3000:]
    imported, config, rows = json.loads(result.stdout.strip().splitlines()[-1])
    assert Path(imported).is_relative_to(site)
    assert config == (ROOT / "zoo_configs" / "drqv2.yml").read_text() and rows > 0
