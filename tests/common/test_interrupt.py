"""Ctrl-C: a step inside ``sigint_deferred`` runs to its end, and the command's one line says what was kept."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from sb3_ef.common.interrupt import Interrupted, interrupted_line, sigint_deferred


def test_a_sigint_during_a_deferred_block_arrives_after_it():
    finished = []
    with pytest.raises(KeyboardInterrupt), sigint_deferred():
        os.kill(os.getpid(), signal.SIGINT)
        finished.append(True)  # reached: the signal was held
    assert finished == [True]
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_the_line_names_what_an_interrupted_command_kept():
    assert interrupted_line("sb3-ef pretrain", Interrupted("checkpoint.pt saved")) == (
        "sb3-ef pretrain: interrupted: checkpoint.pt saved"
    )
    assert interrupted_line("sb3-ef train", KeyboardInterrupt()) == "sb3-ef train: interrupted"


LEARN_INTERRUPTED = """
import sys
from stable_baselines3.common.callbacks import BaseCallback
from sb3_ef.common.interrupt import progress_bar_callback
from tests.test_bad_inputs import drqv2_ef

class CtrlC(BaseCallback):
    def _on_step(self):
        if self.num_timesteps == 12:
            raise KeyboardInterrupt
        return True

model = drqv2_ef()
if sys.argv[1] == "helper":
    with progress_bar_callback(CtrlC(), True) as callback:
        model.learn(1000, callback=callback)
else:
    model.learn(1000, callback=CtrlC(), progress_bar=True)
"""


def _interrupted_learn(how: str) -> str:
    root = Path(__file__).parents[2]
    environment = {**os.environ, "PYTHONPATH": str(root), "MUJOCO_GL": "egl"}
    done = subprocess.run(
        [sys.executable, "-c", LEARN_INTERRUPTED, how], capture_output=True, text=True, env=environment, cwd=root
    )
    assert done.returncode != 0
    return done.stderr


def test_ctrl_c_in_learn_with_a_progress_bar_gives_one_traceback():
    err = _interrupted_learn("helper")
    assert err.count("Traceback") == 1 and err.rstrip().endswith("KeyboardInterrupt"), err
    assert "Exception ignored" not in err


def test_model_learn_with_progress_bar_true_gives_one_traceback():
    err = _interrupted_learn("learn")
    assert err.count("Traceback") == 1 and "Exception ignored" not in err, err
