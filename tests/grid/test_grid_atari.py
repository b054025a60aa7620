"""Atari rows of a grid: rl-zoo3's Atari entries (8 envs, AtariWrapper, 4 stacked frames, linear schedules) run as
rl-zoo3 runs them, and evaluations score whole games."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from sb3_ef.analysis.records import read_records
from sb3_ef.grid.grid import constructor_kwargs, grid_runs
from sb3_ef.grid.run import RunPaths, build_eval_env, execute_run

pytest.importorskip("ale_py")


def test_rl_zoo3s_ppo_atari_entry_becomes_a_run_with_its_envs_and_schedules():
    (spec,) = grid_runs(["ppo"], ["PongNoFrameskip-v4"], seeds=1, eval_freq=10_000, n_timesteps=100_000)
    assert (spec.n_envs, spec.frame_stack, spec.action_repeat) == (8, 4, 4)
    assert spec.env_wrapper == ["stable_baselines3.common.atari_wrappers.AtariWrapper"]
    kwargs = constructor_kwargs(spec.hyperparams)
    assert not {"n_envs", "frame_stack", "env_wrapper"} & set(kwargs)
    learning_rate, clip_range = kwargs["learning_rate"], kwargs["clip_range"]
    assert (learning_rate(1.0), learning_rate(0.5), clip_range(0.25)) == pytest.approx((2.5e-4, 1.25e-4, 0.025))


def test_an_evaluation_episode_is_a_whole_game_though_training_ends_one_at_each_lost_life():
    (spec,) = grid_runs(["ppo"], ["BreakoutNoFrameskip-v4"], seeds=1, eval_freq=8, n_timesteps=8)
    env = build_eval_env(spec, seed=0)
    rng = np.random.default_rng(0)
    env.reset()
    lives_lost = 0
    for _ in range(20_000):
        _, _, dones, infos = env.step(rng.integers(env.action_space.n, size=1))
        if "episode" in infos[0]:
            break
        lives_lost += int(dones[0])  # AtariWrapper's life-loss terminal, which the evaluation reads past
    env.close()
    assert infos[0]["lives"] == 0 and lives_lost == 4  # Breakout's five lives, the game over the episode


def test_ppo_ef_trains_and_evaluates_on_pong_from_rl_zoo3s_atari_settings(tmp_path):
    hyperparams = {"n_steps": 16, "batch_size": 64, "n_epochs": 1, "ef_kwargs": {"decoder_channels": 8}}
    (spec,) = grid_runs(
        {"ppo_ef": {"hyperparams": hyperparams}}, ["PongNoFrameskip-v4"], seeds=1, eval_freq=128, n_timesteps=256,
        eval_episodes=1,
    )  # fmt: skip
    result = execute_run(spec, tmp_path)
    assert result.status == "done" and result.steps == 256
    records = read_records(RunPaths.of(tmp_path, spec).records)
    assert [(row["step"], row["frame"]) for row in records] == [(128, 512), (256, 1024)]  # 4 frames per agent step
    assert all(-21 <= row["return"] <= 21 and row["return"] == int(row["return"]) for row in records)


def test_an_atari_run_resumes_from_its_checkpoint(tmp_path):
    (spec,) = grid_runs(
        {"ppo": {"hyperparams": {"n_steps": 16}}}, ["PongNoFrameskip-v4"], seeds=1, eval_freq=128, n_timesteps=384,
        eval_episodes=1,
    )  # fmt: skip
    execute_run(replace(spec, n_timesteps=256), tmp_path, keep_checkpoints=None)
    RunPaths.of(tmp_path, spec).result.unlink()  # the shorter run finished; the longer one resumes from its newest
    result = execute_run(spec, tmp_path)  # checkpoint, written at the start of the rollout after step 128
    assert result.status == "done" and result.resumed_from == 128 and result.steps == 384
    assert [row["step"] for row in read_records(RunPaths.of(tmp_path, spec).records)] == [128, 256, 384]
