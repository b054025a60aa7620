"""PPO-EF and A2C-EF with ``MultiInputPolicy``: EF predicts one image key's frames from the features SB3's
``CombinedExtractor`` computes from every key; the key chosen, saved and checked."""

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from stable_baselines3.common.envs import FakeImageEnv
from stable_baselines3.common.torch_layers import CombinedExtractor
from stable_baselines3.common.vec_env import DummyVecEnv, VecFrameStack

from sb3_ef import A2CEF, PPOEF
from sb3_ef.envs.toy import ToyAgentEnv
from tests.sb3_hosts.test_on_policy import EF

COLOUR = spaces.Box(0.0, 1.0, (3,), np.float32)
#: SB3's CombinedExtractor (NatureCNN: frames of 36x36 or more; EF's decoder: 32 or 64).
POLICY = {"net_arch": [16], "features_extractor_kwargs": {"cnn_output_dim": 16}}


class WithColour(gym.ObservationWrapper):
    """Image observations as a dict: the frames under ``"pixels"`` (and flipped left-right under ``"mirror"``),
    beside ``"colour"``, the newest frame's mean colour in [0, 1]."""

    def __init__(self, env: gym.Env, mirror: bool = False):
        super().__init__(env)
        image = env.observation_space
        self.mirror = mirror
        self.observation_space = spaces.Dict(
            {"pixels": image, "colour": COLOUR, **({"mirror": image} if mirror else {})}
        )

    def observation(self, observation: np.ndarray) -> dict[str, np.ndarray]:
        channels_first = observation.shape[0] < observation.shape[-1]
        newest = observation[-3:] if channels_first else observation[..., -3:]
        colour = newest.mean(axis=(1, 2) if channels_first else (0, 1)) / 255.0
        dict_observation = {"pixels": observation, "colour": np.resize(colour, 3).astype(np.float32)}
        if self.mirror:
            dict_observation["mirror"] = np.ascontiguousarray(observation[..., ::-1])
        return dict_observation


def toy_dict_env(mirror: bool = False) -> gym.Env:
    return WithColour(ToyAgentEnv(size=64, max_episode_steps=20), mirror)


def make(algorithm, env, **kwargs):
    arguments = {"n_steps": 8, "seed": 0, "policy_kwargs": dict(POLICY), **EF}
    if algorithm is PPOEF:
        arguments.update(batch_size=8, n_epochs=1)
    return algorithm("MultiInputPolicy", env, **{**arguments, **kwargs})


@pytest.mark.parametrize("algorithm", [PPOEF, A2CEF])
def test_multi_input_learns_saves_loads_and_predicts(algorithm, tmp_path):
    model = make(algorithm, toy_dict_env(mirror=True), ef_image_key="mirror")
    extractor = model.policy.features_extractor
    assert isinstance(extractor, CombinedExtractor) and extractor.features_dim == 3 + 16 + 16  # colour, mirror, pixels
    assert (model.frame_shape, model.frame_channels) == ((3, 64, 64), 3)
    before = {name: param.detach().clone() for name, param in model.ef.named_parameters()}
    model.learn(256)
    assert model.logger.name_to_value["train/ef_loss"] > 0
    assert all(not th.equal(before[name], param) for name, param in model.ef.named_parameters())
    model.save(tmp_path / "model")
    loaded = algorithm.load(tmp_path / "model", env=toy_dict_env(mirror=True), device="cpu")
    assert loaded.ef_image_key == "mirror"  # saved: the env's two image keys alone would be refused
    env = toy_dict_env(mirror=True)
    observation, _ = env.reset(seed=0)
    batch = {key: np.stack([value] * 3) for key, value in observation.items()}
    for observations in (observation, batch):
        np.testing.assert_array_equal(
            loaded.predict(observations, deterministic=True)[0], model.predict(observations, deterministic=True)[0]
        )
    loaded.learn(16)
    assert "train/ef_loss" in loaded.logger.name_to_value


def test_windows_keep_every_key_and_target_the_image_keys_newest_frames():
    model = make(PPOEF, DummyVecEnv([lambda: toy_dict_env(mirror=True)] * 2), ef_image_key="mirror", ef_rollouts=1)
    model.learn(32)
    buffer = model.rollout_buffer
    model.collect_rollouts(model.env, model._init_callback(None), buffer, model.n_steps)
    mirror = np.concatenate([buffer.observations["mirror"], model._last_obs["mirror"][None]])
    window = model._rollout_windows()(np.arange(16))  # SB3's flat indices env * n_steps + step
    dtypes = {"colour": th.float32, "mirror": th.uint8, "pixels": th.uint8}  # images kept as uint8, once
    assert {key: value.dtype for key, value in model._ef_ring.rollouts[-1][0].items()} == dtypes
    assert {key: value.dtype for key, value in window.observations.items()} == dtypes
    checked = 0
    for index in range(16):
        env_index, step = divmod(index, 8)
        for key, observed in window.observations.items():
            np.testing.assert_array_equal(observed[index].numpy(), buffer.observations[key][step, env_index])
        for i in range(EF["ef_horizon"]):
            if window.future_mask[index, i]:
                newest = mirror[step + i + 1, env_index, -3:]
                np.testing.assert_array_equal(window.future_frames[index, i].numpy(), newest)
                checked += 1
    assert checked > 16
    features, loss, _ = model._ef_loss(window)
    assert th.equal(features, model.policy.extract_features(window.observations)) and loss > 0


def test_the_only_image_key_is_chosen_and_frame_stacks_of_dicts_are_read():
    assert make(A2CEF, toy_dict_env()).ef_image_key == "pixels"
    grey = lambda: WithColour(FakeImageEnv(screen_height=64, screen_width=64))  # noqa: E731  channels last
    model = make(PPOEF, VecFrameStack(DummyVecEnv([grey] * 2), 4))
    assert (model.ef_image_key, model.frame_shape, model.observation_space["pixels"].shape) == (
        "pixels", (1, 64, 64), (4, 64, 64)
    )  # fmt: skip
    model.learn(16)
    assert model.logger.name_to_value["train/ef_loss"] > 0


class NoImage(gym.ObservationWrapper):
    def __init__(self, env: gym.Env):
        super().__init__(env)
        self.observation_space = spaces.Dict({"colour": COLOUR})

    def observation(self, observation: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        return {"colour": observation["colour"]}


@pytest.mark.parametrize(
    ("env", "kwargs", "message"),
    [
        (toy_dict_env(mirror=True), {}, r"expected ef_image_key to name one of \['mirror', 'pixels'\], got none"),
        (toy_dict_env(), {"ef_image_key": "colour"}, r"one of \['pixels'\], got 'colour', a Box\(0.0, 1.0, \(3,\)"),
        (toy_dict_env(), {"ef_image_key": "depth"}, r"one of \['pixels'\], got 'depth'$"),
        (NoImage(toy_dict_env()), {}, r"expected ef_image_key to name one of \[\], got none"),
        (toy_dict_env(), {"ef_kwargs": {"target": "latent"}}, r"expected ef_kwargs target 'pixel', got 'latent'"),
    ],
)
def test_bad_image_keys_are_rejected_at_construction(env, kwargs, message):
    with pytest.raises(ValueError, match=message):
        make(PPOEF, env, **kwargs)
