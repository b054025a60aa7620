"""``sb3-ef train --hyperparams precision:"'bf16'"``: the run trains in bf16, its model keeps the option, and a killed
run resumed from its checkpoint ends bit for bit where the uninterrupted run ends."""

from __future__ import annotations

import torch as th

from sb3_ef import DrQv2EF
from sb3_ef.zoo import train
from tests.helpers.zoo import HYPERPARAMS as TINY
from tests.helpers.zoo import cli_pairs

ENV_ID, ENV_NAME = "toy/agent-v0", "toy-agent-v0"
HYPERPARAMS = {**TINY["drqv2_ef"], "precision": "bf16", "learning_starts": 20, "babbling_steps": 10}


def _argv(log_folder) -> list[str]:
    # Episodes of 20 steps: the checkpoint at 40 falls between two, where a resume is exact.
    return [
        "--algo", "drqv2_ef", "--env", ENV_ID, "-n", "60", "-f", str(log_folder), "--seed", "0", "--eval-freq", "-1",
        "--save-freq", "40", "--checkpoint-buffer", "--num-threads", "1", "--verbose", "0",
        "--env-kwargs", "size:32", "max_episode_steps:20", "distractor:False", "--hyperparams", *cli_pairs(HYPERPARAMS),
    ]  # fmt: skip


def test_a_resumed_bf16_run_ends_where_the_uninterrupted_one_ends(tmp_path):
    train.main(_argv(tmp_path / "a"))
    train.main(_argv(tmp_path / "b"))
    killed = tmp_path / "b" / "drqv2_ef" / f"{ENV_NAME}_1"
    (killed / f"{ENV_NAME}.zip").unlink()  # a killed run has no final model and is not marked finished
    (killed / ENV_NAME / "result.json").unlink()
    train.main(["--resume", str(killed)])
    uninterrupted = DrQv2EF.load(tmp_path / "a" / "drqv2_ef" / f"{ENV_NAME}_1" / f"{ENV_NAME}.zip", device="cpu")
    resumed = DrQv2EF.load(killed / f"{ENV_NAME}.zip", device="cpu")
    assert uninterrupted.precision == resumed.precision == "bf16"
    assert resumed.num_timesteps == 60 and resumed._n_updates == uninterrupted._n_updates > 0
    expected, got = uninterrupted.policy.state_dict(), resumed.policy.state_dict()
    for key, value in expected.items():
        assert th.equal(value, got[key]), key
