"""SB3's contract on DrQv2-EF and DrQ-v2: load with the constructor's policy_kwargs, the policy saved alone,
channels-last frames."""

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from gymnasium import ObservationWrapper, spaces
from stable_baselines3.common.callbacks import BaseCallback

from sb3_ef.drqv2 import DrQv2, DrQv2EF
from sb3_ef.envs.toy import ToyAgentEnv
from tests.helpers.drqv2 import TINY_ALGO, make_cue_env

# JSON-like values (lists, not tuples): SB3 stores policy_kwargs as JSON when it can, and compares the loaded ones.
EF_POLICY = {
    "net_arch": [32, 32],
    "trunk_dim": 16,
    "features_dim": 64,
    "agent_dim": 8,
    "ef_kwargs": {"rollout_hidden_dims": [16], "decoder_channels": 8},
}
PLAIN_POLICY = {"net_arch": [32, 32], "trunk_dim": 16}
PLAIN_ALGO = {key: value for key, value in TINY_ALGO.items() if key not in ("ef_horizon", "babbling_steps")}
VARIANTS = {DrQv2EF: (EF_POLICY, TINY_ALGO), DrQv2: (PLAIN_POLICY, PLAIN_ALGO)}


def make(algorithm, env=None, **kwargs):
    policy_kwargs, algo_kwargs = VARIANTS[algorithm]
    arguments = {**algo_kwargs, "policy_kwargs": {**policy_kwargs}, "seed": 0, **kwargs}
    return algorithm("CnnPolicy", env if env is not None else make_cue_env(), **arguments)


@pytest.mark.parametrize("algorithm", VARIANTS)
def test_load_with_the_constructors_policy_kwargs(algorithm, tmp_path):
    model = make(algorithm)
    policy_kwargs = VARIANTS[algorithm][0]
    assert model.policy_kwargs == policy_kwargs  # nothing the algorithm derives is written into them
    # ...but the policy got the variant's own defaults.
    assert model.policy.features_dim == (64 if algorithm is DrQv2EF else None)
    model.save(tmp_path / "model.zip")

    loaded = algorithm.load(tmp_path / "model.zip", env=make_cue_env(), policy_kwargs=dict(policy_kwargs))
    assert loaded.policy_kwargs == policy_kwargs
    assert (getattr(loaded, "ef_horizon", None), loaded.policy.features_dim) == (
        getattr(model, "ef_horizon", None),
        model.policy.features_dim,
    )
    with pytest.raises(ValueError, match="policy kwargs do not equal the stored policy kwargs"):
        algorithm.load(tmp_path / "model.zip", env=make_cue_env(), policy_kwargs={**policy_kwargs, "trunk_dim": 8})


@pytest.mark.parametrize("algorithm", VARIANTS)
def test_policy_saved_alone_predicts_as_the_model(algorithm, tmp_path):
    model = make(algorithm).learn(20)
    model.policy.save(tmp_path / "policy.pt")
    loaded = type(model.policy).load(tmp_path / "policy.pt")
    saved = model.policy.state_dict()
    assert loaded.state_dict().keys() == saved.keys()  # the auxiliary module's weights too
    for name, value in saved.items():
        th.testing.assert_close(loaded.state_dict()[name], value, rtol=0, atol=0)
    observations = np.stack([make_cue_env().reset(seed=seed)[0] for seed in range(4)])
    expected, _ = model.predict(observations, deterministic=True)
    actions, _ = loaded.predict(observations, deterministic=True)
    np.testing.assert_array_equal(actions, expected)


class ChannelsLast(ObservationWrapper):
    """An env's frames as (height, width, channels), the usual layout of image envs."""

    def __init__(self, env):
        super().__init__(env)
        channels, height, width = env.observation_space.shape
        self.observation_space = spaces.Box(0, 255, (height, width, channels), np.uint8)

    def observation(self, observation: np.ndarray) -> np.ndarray:
        return observation.transpose(1, 2, 0)


@pytest.mark.parametrize(("size", "frame_stack"), [(64, 1), (32, 3), (84, 1)])
def test_channels_last_frames_are_transposed_as_sb3_does(size, frame_stack):
    # 64x64x3 and 32x32x9 were refused; 84x84x3 passes either way (84 is a multiple of 3).
    env = ChannelsLast(ToyAgentEnv(size=size, frame_stack=frame_stack, max_episode_steps=20))
    model = make(DrQv2EF, env=env, learning_starts=8).learn(10)
    assert model.observation_space.shape == (3 * frame_stack, size, size)
    assert model.policy.frame_shape == (3, size, size)
    observation = env.reset(seed=0)[0]
    action, _ = model.predict(observation, deterministic=True)
    channels_first, _ = model.predict(observation.transpose(2, 0, 1), deterministic=True)
    np.testing.assert_array_equal(action, channels_first)


class PredictDuringTraining(BaseCallback):
    """Calls ``model.predict`` on channels-last observations while training, as an ``EvalCallback`` would."""

    def __init__(self, observation: np.ndarray):
        super().__init__()
        self.observation = observation
        self.predicted: list[tuple[np.ndarray, np.ndarray]] = []

    def _on_step(self) -> bool:
        single, _ = self.model.predict(self.observation)
        batch, _ = self.model.predict(np.stack([self.observation] * 3))
        self.predicted.append((single, batch))
        return True


def test_channels_last_observations_while_babbling_in_evaluation():
    env = ChannelsLast(ToyAgentEnv(size=32, frame_stack=3, max_episode_steps=20))
    model = make(DrQv2EF, env=env, babbling_steps=100, babbling_in_eval=True)
    probe = PredictDuringTraining(env.reset(seed=0)[0])
    model.learn(3, callback=probe)
    for single, batch in probe.predicted:
        assert single.shape == (2,) and np.all(np.abs(single) == 1.0)  # one babbling action
        assert batch.shape == (3, 2) and np.all(np.abs(batch) == 1.0)


class Frames(gym.Env):
    """An env that only declares its spaces (the checks run at construction)."""

    def __init__(self, shape: tuple[int, int, int]):
        self.observation_space = spaces.Box(0, 255, shape, np.uint8)
        self.action_space = spaces.Box(-1.0, 1.0, (2,), np.float32)


@pytest.mark.parametrize("shape", [(4, 32, 32), (32, 32, 4)])
def test_frames_that_are_not_rgb_are_refused_in_either_layout(shape):
    # SB3 transposes the channels-last space: the check names the space the policy would get.
    with pytest.raises(ValueError, match=r"\(3 \* frame_stack, height, width\), got Box\(0, 255, \(4, 32, 32\)"):
        make(DrQv2EF, env=Frames(shape))
