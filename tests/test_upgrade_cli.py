"""``sb3-ef upgrade``: a 0.1.0 model file converted once, nothing written over, a current file refused."""

import subprocess
import sys
from pathlib import Path

from sb3_ef import DrQv2EF

LEGACY = Path(__file__).parent / "drqv2" / "data" / "drqv2ef_0.1.0.zip"


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "sb3_ef.cli", "upgrade", *args], capture_output=True, text=True)


def test_upgrade_writes_a_file_this_version_loads_and_keeps_the_original(tmp_path):
    original = LEGACY.read_bytes()
    result = run(str(LEGACY), str(tmp_path / "new.zip"))
    assert result.returncode == 0, result.stderr
    assert "load it with DrQv2EF.load" in result.stdout
    assert DrQv2EF.load(tmp_path / "new.zip", device="cpu").ef is not None
    assert LEGACY.read_bytes() == original


def test_upgrade_refuses_to_write_over_a_file_and_to_upgrade_a_current_one(tmp_path):
    (tmp_path / "taken.zip").write_bytes(b"mine")
    result = run(str(LEGACY), str(tmp_path / "taken.zip"))
    assert result.returncode == 2 and "exists" in result.stderr and "Traceback" not in result.stderr
    assert (tmp_path / "taken.zip").read_bytes() == b"mine"
    assert run(str(LEGACY), str(tmp_path / "new.zip")).returncode == 0
    again = run(str(tmp_path / "new.zip"), str(tmp_path / "newer.zip"))
    assert again.returncode == 2 and "nothing to upgrade" in again.stderr and not (tmp_path / "newer.zip").exists()


def test_upgrade_into_a_missing_folder_names_the_folder(tmp_path):
    result = run(str(LEGACY), str(tmp_path / "missing" / "new.zip"))
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert f"No folder {tmp_path / 'missing'} to write {tmp_path / 'missing' / 'new.zip'} into" in result.stderr
    assert ".tmp" not in result.stderr
