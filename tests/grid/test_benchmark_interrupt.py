"""Ctrl-C in a terminal (SIGINT to the whole process group) during ``sb3-ef benchmark``: one line, a prompt exit,
no worker left, the run's checkpoint kept, and the next invocation resumes from it."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from multiprocessing import get_context
from pathlib import Path

import pytest

from sb3_ef.grid.local_worker import set_up_worker, sigint_held_for_workers
from tests.grid.test_benchmark_orphans import alive, children, wait_for

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads processes from /proc")

TINY_GRID = Path(__file__).parent / "tiny_grid.yml"
#: Generous bound on the exit after Ctrl-C (about 2 s on 2 loaded cores; the driver waits 5 s at most for its
#: workers to end before it kills them).
EXIT_S = 8.0


def _benchmark(out: Path) -> subprocess.Popen:
    command = ["sb3-ef", "benchmark", str(TINY_GRID), "--out", str(out), "--runs", "drqv2/*_s0"]
    environment = {**os.environ, "OMP_NUM_THREADS": "1"}
    # A session of its own, so that the signal reaches the driver and its workers as a terminal's Ctrl-C does.
    return subprocess.Popen(
        command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=environment, start_new_session=True
    )


def _interrupt_when(process: subprocess.Popen, ready: Callable[[str], bool]) -> str:
    """Send Ctrl-C once ``ready(output so far)``; check the driver's end (one line, status 130, a prompt exit, its
    worker gone) and return the whole output."""
    assert process.stdout is not None
    output = ""
    try:
        for line in process.stdout:
            output += line
            if ready(output):
                break
        [worker] = children(process.pid)
        sent = time.monotonic()
        os.killpg(process.pid, signal.SIGINT)
        rest, _ = process.communicate(timeout=60)
        exited_s = time.monotonic() - sent
    finally:
        process.kill()
    output += rest
    assert process.returncode == 130, output
    assert "Traceback" not in output and "KeyboardInterrupt" not in output, output
    assert output.splitlines()[-1].startswith("sb3-ef benchmark: interrupted: finished runs are kept in"), output
    assert exited_s < EXIT_S, f"{exited_s:.1f} s to exit"
    assert wait_for(lambda: not alive(worker), 5), "the worker outlived the interrupted driver"
    print(f"Ctrl-C: exited after {exited_s:.2f} s", file=sys.stderr)
    return output


def test_ctrl_c_as_a_run_starts_is_one_line_and_a_prompt_exit(tmp_path):
    """Ctrl-C while the run's worker starts (importing torch, building the run); the slow test stops one training."""
    _interrupt_when(_benchmark(tmp_path / "out"), lambda output: "] start " in output)


@pytest.mark.parametrize("held", [True, False])
def test_a_ctrl_c_while_a_worker_starts_python_waits_for_its_set_up(held):
    """The race a loaded machine shows: SIGINT before the worker's initializer. Held, it is discarded there."""
    process = get_context("spawn").Process(target=set_up_worker, args=(os.getpid(),))
    with sigint_held_for_workers() if held else contextlib.nullcontext():
        process.start()
    assert process.pid is not None
    os.kill(process.pid, signal.SIGINT)  # at once: the worker is still starting Python
    process.join(60)
    if held:
        assert process.exitcode == 0
    else:  # killed by SIGINT, or a KeyboardInterrupt traceback from its start-up
        assert process.exitcode in (1, -signal.SIGINT)


@pytest.mark.slow
def test_ctrl_c_keeps_the_checkpoint_and_the_rerun_resumes_from_it(tmp_path):
    out = tmp_path / "out"
    checkpoint = out / "drqv2" / "dmc-cartpole-balance-v0_s0" / "checkpoints" / "rl_model_100_steps.zip"
    # The progress lines come every 10 s: poll the checkpoint between them.
    _interrupt_when(_benchmark(out), lambda output: wait_for(checkpoint.exists, 240))
    assert checkpoint.is_file() and not list(checkpoint.parent.glob(".*"))  # no half-written file left
    rerun = _benchmark(out)
    output, _ = rerun.communicate(timeout=300)
    assert rerun.returncode == 0, output
    assert "(resumed from step 100)" in output, output
