"""Running ``sb3-ef`` in a child process, to stop it with a real SIGINT or run it under a file-size limit."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable

#: Imports, then caps the size of any file this process writes (a write past it fails as on a full disk: EFBIG).
FILE_SIZE_LIMIT = """
import resource, signal, sys
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
{imports}
resource.setrlimit(resource.RLIMIT_FSIZE, ({limit}, {limit}))
{call}
"""


def sb3_ef_process(*argv: str) -> subprocess.Popen:
    """``sb3-ef argv`` in a child process (stderr captured)."""
    environment = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl"), "PYTHONUNBUFFERED": "1"}
    command = [sys.executable, "-m", "sb3_ef.cli", *argv]
    return subprocess.Popen(command, stderr=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=environment)


def interrupt_when(process: subprocess.Popen, ready: Callable[[], bool], timeout: float = 120) -> tuple[int, str]:
    """Send SIGINT to ``process`` once ``ready()`` holds; returns its exit status and stderr."""
    deadline = time.monotonic() + timeout
    while not ready():
        if process.poll() is not None or time.monotonic() > deadline:
            process.kill()
            raise AssertionError(f"never ready (exit status {process.poll()}): {process.communicate()[1]}")
        time.sleep(0.1)
    process.send_signal(signal.SIGINT)
    _, err = process.communicate(timeout=timeout)
    return process.returncode, err


def run_with_file_size_limit(imports: str, call: str, limit: int) -> subprocess.CompletedProcess:
    """``call`` in a child Python whose writes past ``limit`` bytes per file fail (as on a full disk)."""
    code = FILE_SIZE_LIMIT.format(imports=imports, call=call, limit=limit)
    environment = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=environment, timeout=300)
