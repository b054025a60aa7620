"""SB3's contract on SAC-EF, TD3-EF and TQC-EF: policy-only save/load, load with the constructor's policy_kwargs,
batch-norm statistics of the critic target, channels-last frames."""

from pathlib import Path

import numpy as np
import pytest
import torch as th
from gymnasium import ObservationWrapper, spaces
from sb3_contrib import TQC
from stable_baselines3 import SAC, TD3
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from torch import nn

from sb3_ef import SACEF, TD3EF, TQCEF
from sb3_ef.drqv2.policies import DrQv2Encoder
from sb3_ef.envs.toy import ToyAgentEnv
from sb3_ef.upgrade import upgrade

HOSTS = {SACEF: SAC, TD3EF: TD3, TQCEF: TQC}
EF = {"ef_horizon": 3, "agent_dim": 8, "ef_kwargs": {"rollout_hidden_dims": [16], "decoder_channels": 8}}
SMALL = {"buffer_size": 200, "learning_starts": 10, "batch_size": 8, "seed": 0}


def policy_kwargs() -> dict:
    """A small CNN for 32x32 frames, as a new dict each time (SB3's SAC and TQC add ``use_sde`` to theirs)."""
    return {
        "net_arch": [16],
        "normalize_images": False,
        "features_extractor_class": DrQv2Encoder,
        "features_extractor_kwargs": {"features_dim": 32},
    }


def toy_env(**kwargs) -> ToyAgentEnv:
    return ToyAgentEnv(size=32, max_episode_steps=20, **kwargs)


@pytest.mark.parametrize("algorithm", HOSTS)
def test_policy_saved_alone_loads_into_the_hosts_policy_class(algorithm, tmp_path):
    model = algorithm("CnnPolicy", toy_env(), policy_kwargs=policy_kwargs(), **EF, **SMALL).learn(12)
    assert model.ef is not None  # EF is on, and trained by the step above
    model.policy.save(tmp_path / "policy.pt")
    host_policy = HOSTS[algorithm]("CnnPolicy", toy_env(), policy_kwargs=policy_kwargs(), buffer_size=10).policy
    assert type(model.policy) is type(host_policy)  # SB3's own policy class

    loaded = type(model.policy).load(tmp_path / "policy.pt")
    observation = np.stack([toy_env().reset(seed=seed)[0] for seed in range(4)])
    expected, _ = model.policy.predict(observation, deterministic=True)
    actions, _ = loaded.predict(observation, deterministic=True)
    np.testing.assert_allclose(actions, expected, rtol=0, atol=1e-6)


@pytest.mark.parametrize("algorithm", HOSTS)
def test_ef_is_saved_with_the_model(algorithm, tmp_path):
    model = algorithm("CnnPolicy", toy_env(), policy_kwargs=policy_kwargs(), **EF, **SMALL).learn(12)
    model.save(tmp_path / "model.zip")
    loaded = algorithm.load(tmp_path / "model.zip", env=toy_env(), device="cpu")
    for (name, value), (loaded_name, loaded_value) in zip(
        model.ef.state_dict().items(), loaded.ef.state_dict().items(), strict=True
    ):
        assert name == loaded_name
        th.testing.assert_close(loaded_value, value, rtol=0, atol=0)
    assert loaded.auxiliary_optimizer.state_dict()["state"]  # EF's Adam state comes back too


@pytest.mark.parametrize("algorithm", HOSTS)
def test_load_accepts_the_policy_kwargs_the_host_accepts(algorithm, tmp_path):
    """SB3's load compares the given policy_kwargs with the stored ones: EF adds nothing to them, so the kwargs that
    load the host's own zip (SAC and TQC store ``use_sde`` with them, TD3 nothing) load the EF variant's."""
    host = HOSTS[algorithm]("CnnPolicy", toy_env(), policy_kwargs=policy_kwargs(), buffer_size=10)
    model = algorithm("CnnPolicy", toy_env(), policy_kwargs=policy_kwargs(), **EF, **SMALL)
    assert model.policy_kwargs == host.policy_kwargs
    model.save(tmp_path / "model.zip")
    loaded = algorithm.load(tmp_path / "model.zip", env=toy_env(), policy_kwargs=dict(host.policy_kwargs))
    assert loaded.ef is not None


class BatchNormCNN(BaseFeaturesExtractor):
    """A conv layer with batch norm, for 32x32 frames."""

    def __init__(self, observation_space: spaces.Box, features_dim: int = 32):
        super().__init__(observation_space, features_dim)
        channels, height, _ = observation_space.shape
        conv_size = (height - 3) // 2 + 1
        self.net = nn.Sequential(
            nn.Conv2d(channels, 8, 3, stride=2),
            nn.BatchNorm2d(8),
            nn.ReLU(),
            nn.Flatten(),
            nn.Linear(8 * conv_size**2, features_dim),
        )

    def forward(self, observations: th.Tensor) -> th.Tensor:
        return self.net(observations.float() / 255.0)


def batch_norm_stats(module: nn.Module) -> dict[str, th.Tensor]:
    return {name: value for name, value in module.state_dict().items() if "running_" in name}


@pytest.mark.parametrize("algorithm", [SACEF, SAC, TD3EF, TD3, TQCEF, TQC])
def test_critic_target_keeps_the_critics_batch_norm_statistics(algorithm):
    # SB3 copies the critic's running statistics to the critic target with each target update; EF's own forward
    # on the critic's encoder leaves them as the host's updates left them. 20 updates: TD3's last one (even)
    # updates its targets.
    kwargs = {"net_arch": [16], "normalize_images": False, "features_extractor_class": BatchNormCNN}
    extra = EF if algorithm in HOSTS else {}
    model = algorithm("CnnPolicy", toy_env(), policy_kwargs=kwargs, **extra, **SMALL).learn(30)
    critic = batch_norm_stats(model.critic.features_extractor)
    target = batch_norm_stats(model.critic_target.features_extractor)
    assert critic["net.1.running_mean"].abs().sum() > 0  # the statistics moved during training
    for name, value in critic.items():
        th.testing.assert_close(target[name], value, rtol=0, atol=0)


class ChannelsLast(ObservationWrapper):
    """The toy env's frames as (height, width, 3 * frame_stack), the usual layout of image envs."""

    def __init__(self, env: ToyAgentEnv):
        super().__init__(env)
        channels, height, width = env.observation_space.shape
        self.observation_space = spaces.Box(0, 255, (height, width, channels), np.uint8)

    def observation(self, observation: np.ndarray) -> np.ndarray:
        return observation.transpose(1, 2, 0)


@pytest.mark.parametrize("frame_stack", [1, 3])
def test_channels_last_frames_are_transposed_as_sb3_does(frame_stack):
    env = ChannelsLast(toy_env(frame_stack=frame_stack))
    model = SACEF("CnnPolicy", env, policy_kwargs=policy_kwargs(), **EF, **SMALL).learn(12)
    assert model.observation_space.shape == (3 * frame_stack, 32, 32)
    action, _ = model.predict(env.reset(seed=0)[0], deterministic=True)
    assert action.shape == (2,)


def test_a_model_saved_by_sb3_ef_0_1_0_loads_once_upgraded(tmp_path):
    # Written by data/make_sacef_zip.py under sb3-ef 0.1.0, which saved EF's weights inside the policy's.
    data = Path(__file__).parent / "data"
    expected = np.load(data / "sacef_0.1.0_expected.npz")
    with pytest.raises(ValueError, match="sb3-ef upgrade"):
        SACEF.load(data / "sacef_0.1.0.zip")
    upgrade(data / "sacef_0.1.0.zip", tmp_path / "upgraded.zip")
    model = SACEF.load(tmp_path / "upgraded.zip", env=toy_env(), device="cpu")
    assert not any(name.startswith("ef.") for name in model.policy.state_dict())
    for name, value in model.ef.state_dict().items():
        np.testing.assert_array_equal(value.numpy(), expected[f"ef/{name}"])
    observations = np.stack([toy_env().reset(seed=seed)[0] for seed in range(3)])
    np.testing.assert_array_equal(model.predict(observations, deterministic=True)[0], expected["actions"])
    model.learn(2, reset_num_timesteps=False)  # EF's optimiser state came back with it and steps on
    model.save(tmp_path / "model.zip")
    assert SACEF.load(tmp_path / "model.zip", env=toy_env()).ef is not None


@pytest.mark.parametrize("algorithm", HOSTS)
def test_load_accepts_the_policy_kwargs_given_to_the_constructor(algorithm, tmp_path):
    """SAC and TQC add ``use_sde`` to the stored kwargs: the caller's own dict still loads the model."""
    algorithm("CnnPolicy", toy_env(), policy_kwargs=policy_kwargs(), **EF, **SMALL).save(tmp_path / "model.zip")
    loaded = algorithm.load(tmp_path / "model.zip", env=toy_env(), policy_kwargs=policy_kwargs())
    assert loaded.ef is not None


@pytest.mark.parametrize("algorithm", HOSTS)
def test_gradient_steps_0_collects_without_training(algorithm):
    model = algorithm("CnnPolicy", toy_env(), policy_kwargs=policy_kwargs(), gradient_steps=0, **EF, **SMALL)
    before = {name: value.clone() for name, value in model.auxiliary.state_dict().items()}
    model.learn(20)
    assert model.replay_buffer.size() > 0 and model._n_updates == 0
    assert all(th.equal(value, before[name]) for name, value in model.auxiliary.state_dict().items())


def test_ef_sizes_in_policy_kwargs_are_refused_naming_the_argument():
    with pytest.raises(ValueError, match=r"SACEF takes \['agent_dim'\] as its own arguments"):
        SACEF("CnnPolicy", toy_env(), policy_kwargs={**policy_kwargs(), "agent_dim": 8}, **SMALL)


@pytest.mark.parametrize("algorithm", HOSTS)
def test_the_host_algorithms_zip_is_refused_naming_its_class(algorithm, tmp_path):
    HOSTS[algorithm]("CnnPolicy", toy_env(), policy_kwargs=policy_kwargs(), buffer_size=10).save(tmp_path / "m.zip")
    plain = HOSTS[algorithm].__name__
    with pytest.raises(ValueError, match=rf"saved by .*own {plain}, without {algorithm.__name__}.*{plain}\.load"):
        algorithm.load(tmp_path / "m.zip")
