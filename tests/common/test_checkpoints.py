"""Resumable checkpoints: atomic files, pruning, and a killed-and-resumed run equal to an uninterrupted one."""

from __future__ import annotations

import numpy as np
import pytest
import torch as th
from stable_baselines3.common.vec_env import DummyVecEnv

from sb3_ef import DrQv2EF, MotorBabblingCallback
from sb3_ef.common.checkpoints import (
    ResumableCheckpointCallback,
    latest_checkpoint,
    list_checkpoints,
    load_checkpoint,
)
from sb3_ef.envs.toy import ToyAgentEnv

EPISODE = 25


def _env() -> DummyVecEnv:
    # No distractor: the toy env then draws random numbers only in reset (see the checkpoints module).
    return DummyVecEnv([lambda: ToyAgentEnv(size=32, max_episode_steps=EPISODE, distractor=False)])


def _model(env: DummyVecEnv, babbling_steps: int = 30) -> DrQv2EF:
    return DrQv2EF(
        "CnnPolicy",
        env,
        buffer_size=500,
        learning_starts=40,
        batch_size=8,
        babbling_steps=babbling_steps,
        ef_horizon=3,
        policy_kwargs={"features_dim": 32, "agent_dim": 8, "net_arch": [32], "trunk_dim": 16},
        seed=3,
    )


def _parameters(model: DrQv2EF) -> dict[str, th.Tensor]:
    return {name: value.clone() for name, value in model.policy.state_dict().items()}


def test_killed_and_resumed_run_equals_uninterrupted(tmp_path):
    total, checkpoint_step = 4 * EPISODE, 2 * EPISODE
    uninterrupted = _model(_env())
    uninterrupted.learn(total, callback=ResumableCheckpointCallback(checkpoint_step, str(tmp_path / "a")))

    # The "killed" run goes on past its checkpoint (as a run killed later would) and is thrown away.
    killed = _model(_env())
    killed.learn(checkpoint_step + 10, callback=ResumableCheckpointCallback(checkpoint_step, str(tmp_path / "b")))
    checkpoint = latest_checkpoint(tmp_path / "b")
    assert checkpoint is not None and checkpoint.step == checkpoint_step
    assert checkpoint.replay_buffer_path is not None and checkpoint.rng_path is not None
    del killed
    np.random.seed(123), th.manual_seed(123)  # a fresh process draws other numbers

    resumed = load_checkpoint(DrQv2EF, checkpoint, _env())
    assert resumed.num_timesteps == checkpoint_step and resumed.replay_buffer.size() == checkpoint_step
    resumed.learn(total - checkpoint_step, reset_num_timesteps=False)

    assert resumed.num_timesteps == total and resumed._n_updates == uninterrupted._n_updates > 0
    expected, got = _parameters(uninterrupted), _parameters(resumed)
    for name, value in expected.items():
        assert th.equal(value, got[name]), name


def _babbling(form: str) -> list[MotorBabblingCallback]:
    """The callbacks of each ``learn`` for a babbling form: the host's own (constructor), or adaptive babbling."""
    if form == "constructor":
        return []
    eval_env = ToyAgentEnv(size=32, max_episode_steps=EPISODE, distractor=False)
    return [
        MotorBabblingCallback(
            "adaptive", min_steps=60, max_steps=90, patience=2, eval_freq=20, eval_env=eval_env, holdout_steps=40,
            holdout_windows=8,
        )
    ]  # fmt: skip


def _stored_actions(model: DrQv2EF) -> np.ndarray:
    buffer = model.replay_buffer
    return np.asarray(buffer.actions[: buffer.size(), 0])


@pytest.mark.parametrize("form", ["constructor", "adaptive"])
def test_a_resumed_run_continues_babbling_exactly(form, tmp_path):
    """The checkpoint at step 50 falls inside the babbling stage (70 steps, or adaptive from 60 to 90 steps)."""
    total, checkpoint_step = 4 * EPISODE, 2 * EPISODE
    babbling_steps = 70 if form == "constructor" else 0
    uninterrupted = _model(_env(), babbling_steps)
    babbling = _babbling(form)
    uninterrupted.learn(total, callback=[*babbling, ResumableCheckpointCallback(checkpoint_step, str(tmp_path / "a"))])

    killed = _model(_env(), babbling_steps)
    killed.learn(
        checkpoint_step + 10,
        callback=[*_babbling(form), ResumableCheckpointCallback(checkpoint_step, str(tmp_path / "b"))],
    )
    del killed
    np.random.seed(123), th.manual_seed(123)
    resumed = load_checkpoint(DrQv2EF, latest_checkpoint(tmp_path / "b"), _env())
    resumed_babbling = _babbling(form)
    resumed.learn(total - checkpoint_step, reset_num_timesteps=False, callback=resumed_babbling)

    actions, resumed_actions = _stored_actions(uninterrupted), _stored_actions(resumed)
    np.testing.assert_array_equal(actions, resumed_actions)
    end = uninterrupted._motor_babbling.end_step
    assert resumed._motor_babbling.end_step == end and checkpoint_step < end < total
    assert np.all(np.abs(actions[:end]) == 1.0) and not np.all(np.abs(actions[end:]) == 1.0)
    if form == "adaptive":
        assert resumed_babbling[0].state.scores == babbling[0].state.scores
        assert [step for step, _ in babbling[0].state.scores][:2] == [40, 60]  # one evaluation before the checkpoint
    expected, got = _parameters(uninterrupted), _parameters(resumed)
    for name, value in expected.items():
        assert th.equal(value, got[name]), name


def test_keep_none_keeps_every_checkpoint(tmp_path):
    model = _model(_env())
    model.learn(60, callback=ResumableCheckpointCallback(10, str(tmp_path), keep=None))
    assert [checkpoint.step for checkpoint in list_checkpoints(tmp_path)] == [10, 20, 30, 40, 50]


def test_checkpoints_hold_the_transition_of_their_step_and_are_pruned(tmp_path):
    model = _model(_env())
    callback = ResumableCheckpointCallback(10, str(tmp_path), keep=2)
    model.learn(60, callback=callback)
    checkpoints = list_checkpoints(tmp_path)
    assert [checkpoint.step for checkpoint in checkpoints] == [40, 50]  # 60 ends learn before the next rollout
    assert sorted(path.name for path in tmp_path.iterdir()) == sorted(
        path.name
        for checkpoint in checkpoints
        for path in (checkpoint.model_path, checkpoint.replay_buffer_path, checkpoint.rng_path)
    )
    loaded = load_checkpoint(DrQv2EF, checkpoints[-1], _env())
    assert loaded.replay_buffer.size() == loaded.num_timesteps == 50


def test_an_interrupted_write_leaves_the_previous_checkpoint(tmp_path):
    model = _model(_env())
    model.learn(30, callback=ResumableCheckpointCallback(10, str(tmp_path)))
    assert latest_checkpoint(tmp_path).step == 20
    (tmp_path / "rl_model_30_steps.zip.tmp").write_bytes(b"half a zip")  # killed while writing step 30
    (tmp_path / "rl_model_replay_buffer_30_steps.pkl").write_bytes(b"")
    assert latest_checkpoint(tmp_path).step == 20


def test_a_checkpoint_without_buffer_or_random_states_still_loads(tmp_path):
    model = _model(_env())
    model.learn(30, callback=ResumableCheckpointCallback(10, str(tmp_path), save_replay_buffer=False))
    checkpoint = latest_checkpoint(tmp_path)
    assert checkpoint.replay_buffer_path is None
    checkpoint.rng_path.unlink()
    loaded = load_checkpoint(DrQv2EF, latest_checkpoint(tmp_path), _env())
    loaded.learn(4, reset_num_timesteps=False)
    assert loaded.num_timesteps == 24


@pytest.mark.parametrize(
    ("arguments", "named"), [({"save_freq": 0}, "save_freq"), ({"save_freq": 5, "keep": 0}, "keep")]
)
def test_bad_arguments_are_named(arguments, named, tmp_path):
    with pytest.raises(ValueError, match=named):
        ResumableCheckpointCallback(save_path=str(tmp_path), **arguments)
