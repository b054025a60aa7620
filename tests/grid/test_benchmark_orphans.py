"""A local worker does not outlive its driver: killed `sb3-ef benchmark`, no run goes on training unseen (and
racing the next invocation, which trains the same run)."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads processes from /proc")

# The driver starts the local backend's pool and gives it a task that marks its start and then runs for a minute.
DRIVER = """
import os, sys, time
from sb3_ef.grid.backends import LocalBackend

pool = LocalBackend(sys.argv[1])._pool()
pool.submit(os.system, f"echo $$ > {sys.argv[2]}.tmp && mv {sys.argv[2]}.tmp {sys.argv[2]} && exec sleep 60")
time.sleep(120)
"""


def stat_fields(process: Path) -> list[str]:
    """The fields of ``/proc/<pid>/stat`` after the command name: state, parent pid, ..."""
    return (process / "stat").read_text().rsplit(")", 1)[1].split()


def children(pid: int) -> list[int]:
    """The pool workers started by ``pid``."""
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                parent = int(stat_fields(entry)[1])
                command = (entry / "cmdline").read_bytes()
            except OSError:
                continue
            if parent == pid and b"spawn_main" in command:
                found.append(int(entry.name))
    return found


def alive(pid: int) -> bool:
    try:
        state = stat_fields(Path(f"/proc/{pid}"))[0]
    except OSError:
        return False
    return state != "Z"


def wait_for(condition, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.2)
    return condition()


def test_a_worker_ends_when_its_driver_is_killed(tmp_path):
    marker = tmp_path / "task_started"
    driver = subprocess.Popen([sys.executable, "-c", DRIVER, str(tmp_path), str(marker)])
    try:
        assert wait_for(marker.exists, 120), "the pool's worker never started its task"
        (worker,) = children(driver.pid)
        driver.send_signal(signal.SIGKILL)  # no clean-up in the driver: the worker must notice by itself
        driver.wait()
        assert wait_for(lambda: not alive(worker), 15), "the worker went on after its driver was killed"
    finally:
        driver.kill()
        if marker.exists():  # the task's own sleep, left behind by the worker
            with contextlib.suppress(ProcessLookupError):
                os.kill(int(marker.read_text()), signal.SIGKILL)
