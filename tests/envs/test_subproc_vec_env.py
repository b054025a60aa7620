"""Several pixel envs at once: each algorithm trains on two DMC envs rendering in their own processes (EGL in each)."""

from __future__ import annotations

from functools import partial

import numpy as np
import pytest
from stable_baselines3.common.vec_env import SubprocVecEnv

from sb3_ef.drqv2 import DrQv2, DrQv2EF
from sb3_ef.envs import make_env
from sb3_ef.tdmpc2 import TDMPC2, TDMPC2EF

SIZE = 64
DRQV2_POLICY = {"net_arch": [32], "trunk_dim": 16, "features_dim": 64}
TDMPC2_POLICY = {
    "num_channels": 4,
    "mlp_dim": 32,
    "num_q": 2,
    "planner_kwargs": {"iterations": 1, "num_samples": 8, "num_elites": 2, "num_pi_trajs": 2},
}
EF_POLICY = {"agent_dim": 8, "ef_kwargs": {"rollout_hidden_dims": (16,), "decoder_channels": 8}}
ALGORITHMS = {
    DrQv2: ({}, DRQV2_POLICY),
    DrQv2EF: ({"ef_horizon": 3, "babbling_steps": 4}, {**DRQV2_POLICY, **EF_POLICY}),
    TDMPC2: ({}, TDMPC2_POLICY),
    TDMPC2EF: ({"ef_horizon": 3, "babbling_steps": 4}, {**TDMPC2_POLICY, **EF_POLICY}),
}


def two_cartpoles() -> SubprocVecEnv:
    """Two cartpoles with different seeds; forkserver children start clean (no GL context inherited)."""
    makers = [partial(make_env, "dmc/cartpole-swingup", size=SIZE, fast_render=True, seed=seed) for seed in (0, 1)]
    return SubprocVecEnv(makers, start_method="forkserver")


@pytest.mark.parametrize(
    "algorithm",
    [
        DrQv2EF,
        pytest.param(DrQv2, marks=pytest.mark.slow),
        pytest.param(TDMPC2, marks=pytest.mark.slow),
        pytest.param(TDMPC2EF, marks=pytest.mark.slow),
    ],
)
def test_trains_on_two_envs_in_subprocesses(algorithm):
    extra, policy_kwargs = ALGORITHMS[algorithm]
    env = two_cartpoles()
    try:
        model = algorithm(
            "CnnPolicy",
            env,
            buffer_size=400,
            batch_size=8,
            learning_starts=16,
            seed=0,
            policy_kwargs=policy_kwargs,
            **extra,
        )
        model.learn(32)  # 16 steps of both envs: 8 warm-up steps, then updates
        buffer = model.replay_buffer
        assert model.num_timesteps == 32 and buffer.n_envs == 2 and buffer.size() == 32
        assert model._n_updates > 0
        assert all(np.isfinite(value) for key, value in model.logger.name_to_value.items() if key.endswith("loss"))
        # Each env's ring holds its own rendered episode: real frames, different between the two seeds.
        frames = buffer.observations[:16, :, -3:]  # the newest frame of each env's 16 stored observations
        assert frames.std() > 0 and not np.array_equal(frames[:, 0], frames[:, 1])
    finally:
        env.close()
