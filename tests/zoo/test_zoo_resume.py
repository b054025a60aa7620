"""``sb3-ef train`` runs that continue: -i, --resume, checkpoints with the replay buffer, on a real DMC env."""

from __future__ import annotations

import json
import pickle

import numpy as np
import pytest

from sb3_ef.common.checkpoints import latest_checkpoint, list_checkpoints
from sb3_ef.ef.babbling import babble
from sb3_ef.zoo import train
from sb3_ef.zoo.registration import algorithm_classes
from sb3_ef.zoo.resume import with_seed
from tests.helpers.zoo import cli_pairs

ENV_ID = "dmc/cartpole-swingup-v0"
LOG_NAME = "dmc-cartpole-swingup-v0"
LEARNING_STARTS, BABBLING, TOTAL = 20, 50, 100
HYPERPARAMS = {
    "buffer_size": 400,
    "batch_size": 8,
    "learning_starts": LEARNING_STARTS,
    "ef_horizon": 3,
    "babbling_steps": BABBLING,
    "policy_kwargs": {
        "net_arch": [32],
        "trunk_dim": 16,
        "features_dim": 32,
        "agent_dim": 8,
        "ef_kwargs": {"decoder_channels": 8, "rollout_hidden_dims": (16,)},
    },
}


def _args(log_folder, n_timesteps: int) -> list[str]:
    return [
        "--algo", "drqv2_ef", "--env", ENV_ID, "-n", str(n_timesteps), "-f", str(log_folder), "--seed", "0",
        "--eval-freq", "30", "--eval-episodes", "1", "--save-freq", "40", "--checkpoint-buffer",
        "--num-threads", "1", "--verbose", "0", "--save-replay-buffer",
        # Episodes of 40 agent steps (action repeat 2): the checkpoint at 40 falls between two, where a resume is exact.
        "--env-kwargs", *cli_pairs({"size": 64, "fast_render": True, "episode_length": 80}),
        "--hyperparams", *cli_pairs(HYPERPARAMS),
    ]  # fmt: skip


# About 30 s on 2 cores; the tests that need it are slow but one, which checks what a user sees of a resumed run.
@pytest.fixture(scope="module")
def resumed(tmp_path_factory):
    """A run killed after 60 steps (checkpoints at 40), then continued with --resume up to 100 steps."""
    log_folder = tmp_path_factory.mktemp("logs")
    train.main(_args(log_folder, 60))
    run = log_folder / "drqv2_ef" / f"{LOG_NAME}_1"
    # A killed run leaves no final model (a finished one would be continued from it, at step 60).
    (run / f"{LOG_NAME}.zip").unlink()
    (run / "replay_buffer.pkl").unlink()
    first = {
        "checkpoint": latest_checkpoint(run),
        "evaluations": np.load(run / "evaluations.npz")["timesteps"].tolist(),
        "monitor_lines": len((run / "0.monitor.csv").read_text().splitlines()),
    }
    train.main(["--resume", str(run), "-n", str(TOTAL)])
    return run, first


@pytest.mark.slow
def test_checkpoints_hold_model_buffer_and_random_states(resumed):
    _, first = resumed
    checkpoint = first["checkpoint"]
    assert checkpoint.step == 40
    assert checkpoint.replay_buffer_path is not None and checkpoint.rng_path is not None


@pytest.mark.slow
def test_resume_continues_steps_warm_up_babbling_and_buffer(resumed):
    run, _ = resumed
    assert not (run.parent / f"{LOG_NAME}_2").exists()  # the same run folder, not a new one
    model = algorithm_classes()["drqv2_ef"].load(run / f"{LOG_NAME}.zip", device="cpu")
    assert model.num_timesteps == TOTAL
    # One update per 2 steps once past the warm-up, counted over the whole run: the warm-up did not repeat.
    assert model._n_updates == (TOTAL - LEARNING_STARTS) // 2
    with open(run / "replay_buffer.pkl", "rb") as file:
        buffer = pickle.load(file)
    assert buffer.size() == TOTAL  # the 40 steps before the checkpoint are still there
    # The stored actions of the (only) env in step order: the ring has not wrapped.
    actions = buffer.actions[: buffer.size(), 0]
    # Babbling (+-1 actions) went on after the resume at step 40 up to step 50, and stopped there; its draws after
    # the resume continue the seeded stream (the run's --seed 0) of the uninterrupted run.
    rng = np.random.default_rng(np.random.SeedSequence(0).spawn(2)[0])
    np.testing.assert_array_equal(actions[:BABBLING], np.concatenate([babble(rng, (1, 1)) for _ in range(BABBLING)]))
    assert not np.all(np.abs(actions[BABBLING:]) == 1.0)
    assert (model._motor_babbling.end_step, model._motor_babbling.end_reason) == (BABBLING, "steps")


def test_resume_appends_evaluations_and_logs(resumed):
    run, first = resumed
    assert first["evaluations"] == [30, 60]
    # The resumed run starts from the checkpoint at step 40: the evaluation at 60 is redone, then 90.
    evaluations = np.load(run / "evaluations.npz")
    assert evaluations["timesteps"].tolist() == [30, 60, 60, 90]
    # The redone evaluation plays the episode of the first one (the env is reseeded from the step), with the model
    # the exact resume trained again: the same return. A fresh evaluation env would replay the episode of step 30.
    returns = evaluations["results"][:, 0]
    assert returns[1] == returns[2] != returns[0]
    assert len((run / "0.monitor.csv").read_text().splitlines()) > first["monitor_lines"]
    argv = json.loads((run / LOG_NAME / "train_argv.json").read_text())
    assert argv[argv.index("-i") + 1] == str(first["checkpoint"].model_path)
    assert [checkpoint.step for checkpoint in list_checkpoints(run)] == [40, 80]
    # The resumed run keeps the recorded --checkpoint-buffer: its own checkpoint carries the replay buffer too.
    assert all(checkpoint.replay_buffer_path is not None for checkpoint in list_checkpoints(run))


@pytest.mark.slow
def test_continuing_a_finished_run_says_so(resumed):
    run, _ = resumed
    with pytest.raises(ValueError, match=f"already at step {TOTAL}"):
        train.main([*_args(run.parent.parent, TOTAL), "-i", str(run / f"{LOG_NAME}.zip")])


def test_the_saved_arguments_give_the_seed_rl_zoo3_drew():
    assert with_seed(["--algo", "sear"], 7) == ["--algo", "sear", "--seed", "7"]
    assert with_seed(["--seed", "-1"], 7) == ["--seed", "-1", "--seed", "7"]  # argparse: the last value wins
    assert with_seed(["--seed=7", "-n", "5"], 7) == ["--seed=7", "-n", "5"]


def test_bad_resume_and_trained_agent_are_named(tmp_path):
    with pytest.raises(ValueError, match="--resume expects an sb3-ef run folder"):
        train.main(["--resume", str(tmp_path)])
    with pytest.raises(ValueError, match=r"-i expects the path of a saved model \.zip"):
        train.main(["--algo", "drqv2_ef", "--env", ENV_ID, "-i", str(tmp_path / "missing.zip")])


@pytest.mark.slow
def test_a_run_killed_with_sigkill_resumes_from_its_newest_checkpoint(tmp_path):
    """A real `kill -9` of a training process, then --resume: the run ends at its total with its whole buffer."""
    import os
    import signal
    import subprocess
    import sys
    import time

    run = tmp_path / "drqv2_ef" / "toy-agent-v0_1"
    args = [
        "--algo", "drqv2_ef", "--env", "toy/agent-v0", "-n", "300", "-f", str(tmp_path), "--seed", "0",
        "--save-freq", "50", "--checkpoint-buffer", "--save-replay-buffer", "--num-threads", "1", "--verbose", "0",
        "--env-kwargs", "size:32", "max_episode_steps:25",
        "--hyperparams", *cli_pairs({**HYPERPARAMS, "babbling_steps": 0}),
    ]  # fmt: skip
    process = subprocess.Popen(
        [sys.executable, "-m", "sb3_ef.zoo.train", *args], env=os.environ.copy(), stdout=subprocess.DEVNULL
    )
    try:
        deadline = time.monotonic() + 300
        while latest_checkpoint(run) is None or latest_checkpoint(run).step < 100:
            assert process.poll() is None and time.monotonic() < deadline, "no checkpoint before the run ended"
            time.sleep(0.2)
    finally:
        process.send_signal(signal.SIGKILL)
        process.wait()
    killed_at = latest_checkpoint(run).step
    assert not (run / "toy-agent-v0.zip").exists()  # it never finished

    train.main(["--resume", str(run)])
    model = algorithm_classes()["drqv2_ef"].load(run / "toy-agent-v0.zip", device="cpu")
    assert model.num_timesteps == 300 > killed_at
    with open(run / "replay_buffer.pkl", "rb") as file:
        assert pickle.load(file).size() == 300
