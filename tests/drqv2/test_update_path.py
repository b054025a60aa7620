"""The files of sb3-ef that one DrQv2-EF update and one TDMPC2-EF update run, as docs/architecture.md lists them
("One update, file by file"): recorded with ``sys.setprofile`` over one ``train`` round of one gradient step."""

from __future__ import annotations

import os
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

import sb3_ef
from sb3_ef import TDMPC2EF, DrQv2EF
from sb3_ef.envs.toy import ToyAgentEnv
from tests.helpers.drqv2 import TINY_ALGO, TINY_POLICY, make_cue_env
from tests.helpers.tdmpc2 import TINY_EF_POLICY

PACKAGE = os.path.dirname(sb3_ef.__file__)
ARCHITECTURE = Path(__file__).parents[2] / "docs" / "architecture.md"
BUFFER_SAMPLE = {f"common/buffers/{name}.py" for name in ("sequence", "sampling", "storage", "episodes")}
EF = {"auxiliary/host.py", "common/augmentation.py", "ef/foresight.py", "ef/decoder.py"}
UPDATES = {
    "DrQv2-EF": {"drqv2/drqv2.py", "drqv2/policies.py", "common/schedules.py", "common/layers.py"} | EF | BUFFER_SAMPLE,
    "TDMPC2-EF": {
        "tdmpc2/tdmpc2.py", "tdmpc2/sequence.py", "tdmpc2/world_model.py", "tdmpc2/math.py", "tdmpc2/gradients.py",
        "common/layers.py",
    } | EF | BUFFER_SAMPLE,
}  # fmt: skip


def make_drqv2_ef() -> DrQv2EF:
    return DrQv2EF("CnnPolicy", make_cue_env(), policy_kwargs=TINY_POLICY, seed=0, **TINY_ALGO)


def make_tdmpc2_ef() -> TDMPC2EF:
    return TDMPC2EF(
        "CnnPolicy", ToyAgentEnv(size=64, max_episode_steps=20), learning_starts=10, batch_size=4, buffer_size=300,
        ef_horizon=5, babbling_steps=0, seed_burst=False, seed=0, policy_kwargs=TINY_EF_POLICY,
    )  # fmt: skip


def files_of_one_update(make: Callable) -> set[str]:
    model = make()
    model.learning_starts = 31
    model.learn(30)  # fills the buffer, no update
    visited: set[str] = set()

    def record(frame, event, _) -> None:
        if event == "call" and frame.f_code.co_filename.startswith(PACKAGE):
            visited.add(os.path.relpath(frame.f_code.co_filename, PACKAGE).replace(os.sep, "/"))

    sys.setprofile(record)
    try:
        model.train(gradient_steps=1, batch_size=4)
    finally:
        sys.setprofile(None)
    return visited


@pytest.mark.parametrize(("name", "make"), [("DrQv2-EF", make_drqv2_ef), ("TDMPC2-EF", make_tdmpc2_ef)])
def test_one_update_runs_the_files_docs_architecture_lists(name, make):
    assert files_of_one_update(make) == UPDATES[name]
    documented = ARCHITECTURE.read_text().split("### One update, file by file")[1].split("\n### ")[0]
    section = documented.split(f"**{name}**")[1].split("**")[0]
    assert {path for path in UPDATES[name] if f"`{path}`" not in section} == set()
