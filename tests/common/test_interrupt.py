"""Ctrl-C: a step inside ``sigint_deferred`` runs to its end, and the command's one line says what was kept."""

from __future__ import annotations

import os
import signal

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
