"""PPO-EF and A2C-EF: SB3's contract (parts of SB3's test_run, test_save_load and test_predict, adapted), the host's
update left as SB3's, EF's gradient routes, babbling, Atari frames and bad input.

Differences from SB3's tests: image envs (the toy world, FakeImageEnv frames stacked as Atari's) with a small CNN
instead of MlpPolicy on vector envs (EF needs frames); CPU only (no CUDA here) and no torch.compile round trip;
CnnPolicy here (MlpPolicy is refused; MultiInputPolicy: test_on_policy_dict.py)."""

from copy import deepcopy
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from stable_baselines3 import A2C, PPO
from stable_baselines3.common.envs import FakeImageEnv
from stable_baselines3.common.policies import ActorCriticCnnPolicy
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from stable_baselines3.common.vec_env import DummyVecEnv, VecFrameStack
from torch import nn

from sb3_ef import A2CEF, PPOEF
from sb3_ef.common.precision import autocast
from sb3_ef.envs.toy import ToyAgentEnv

HOSTS = {PPOEF: PPO, A2CEF: A2C}
EF = {"ef_horizon": 3, "agent_dim": 8, "ef_kwargs": {"rollout_hidden_dims": (16,), "decoder_channels": 8}}


class SmallCNN(BaseFeaturesExtractor):
    """One strided convolution and a projection, for frames of any channel count (NatureCNN needs 36x36 or more)."""

    def __init__(self, observation_space: spaces.Box, features_dim: int = 32):
        super().__init__(observation_space, features_dim)
        channels, height, width = observation_space.shape
        size = ((height - 3) // 2 + 1) * ((width - 3) // 2 + 1)
        self.net = nn.Sequential(nn.Conv2d(channels, 8, 3, stride=2), nn.ReLU(), nn.Flatten(), nn.Linear(8 * size, 32))

    def forward(self, observations: th.Tensor) -> th.Tensor:
        return self.net(observations)


POLICY = {"net_arch": [16], "features_extractor_class": SmallCNN}


class DiscreteMoves(gym.ActionWrapper):
    """The toy world with 5 discrete actions: stay, up, down, left, right."""

    MOVES = np.array([[0, 0], [-1, 0], [1, 0], [0, -1], [0, 1]], dtype=np.float32)

    def __init__(self, env: gym.Env):
        super().__init__(env)
        self.action_space = spaces.Discrete(5)

    def action(self, action: int) -> np.ndarray:
        return self.MOVES[int(action)]


def toy_env(discrete: bool = False) -> gym.Env:
    env = ToyAgentEnv(size=32, max_episode_steps=20)
    return DiscreteMoves(env) if discrete else env


def grey_stack(n_envs: int = 2) -> VecFrameStack:
    """Atari-like: 4 stacked grey 32x32 frames (channels last, as SB3's wrappers give them), 6 discrete actions."""
    return VecFrameStack(DummyVecEnv([lambda: FakeImageEnv(screen_height=32, screen_width=32)] * n_envs), 4)


def make(algorithm, env, **kwargs):
    """A small model; PPO with one epoch of two minibatches per rollout."""
    arguments = {"n_steps": 8, "seed": 0, "policy_kwargs": dict(POLICY)}  # SB3 writes into the dict it is given
    if algorithm in (PPOEF, PPO):
        arguments.update(batch_size=8, n_epochs=1)
    if algorithm in HOSTS:
        arguments.update(EF)
    return algorithm("CnnPolicy", env, **{**arguments, **kwargs})


def parameters(module: nn.Module) -> dict[str, th.Tensor]:
    return {name: param.detach().clone() for name, param in module.named_parameters()}


@pytest.mark.parametrize("algorithm", HOSTS)
@pytest.mark.parametrize("env", [grey_stack, toy_env])
@pytest.mark.parametrize("normalize_advantage", [False, True])
def test_learn_trains_ef_on_grey_and_rgb_stacks(algorithm, env, normalize_advantage):
    model = make(algorithm, env(), normalize_advantage=normalize_advantage)
    assert model.frame_shape == ((1, 32, 32) if env is grey_stack else (3, 32, 32))
    before = parameters(model.ef)
    model.learn(32)
    assert model.num_timesteps == 32
    logged = model.logger.name_to_value
    assert logged["train/ef_loss"] > 0 and "train/value_loss" in logged and "train/aux_grad_ratio" in logged
    assert all(not th.equal(before[name], param) for name, param in parameters(model.ef).items())


def test_ppo_options_clip_range_vf_and_target_kl():
    model = make(PPOEF, grey_stack(), clip_range_vf=0.2, target_kl=1e-9, n_epochs=3, verbose=1)
    model.learn(16)
    logged = model.logger.name_to_value
    assert logged["train/clip_range_vf"] == 0.2
    assert model._n_updates == 1  # the first epoch's first minibatch passed the KL limit (no update before it)


@pytest.mark.parametrize(("algorithm", "host"), HOSTS.items())
@pytest.mark.parametrize("ef_rollouts", [1, 2])
def test_host_update_is_sb3s_own_plus_efs_gradient_on_the_encoder(algorithm, host, ef_rollouts):
    """The same rollout (EF is built in a forked generator, its draws are its own) and one update: the host's losses
    equal SB3's, its gradient is clipped as SB3 clips it, and EF's gradient moves the shared encoder only (its windows
    at the minibatch's steps, or drawn from the ring and encoded apart)."""
    extra = {"ef_rollouts": ef_rollouts}
    models = [
        make(variant, toy_env(discrete=True), **(extra if variant is algorithm else {})).learn(8)
        for variant in (algorithm, host)
    ]
    logged = [model.logger.name_to_value for model in models]
    names = ("policy_gradient_loss" if host is PPO else "policy_loss", "value_loss", "entropy_loss")
    for name in names:
        assert logged[0][f"train/{name}"] == pytest.approx(logged[1][f"train/{name}"], rel=1e-6, abs=1e-7)
    with_ef, without_ef = (parameters(model.policy) for model in models)
    changed = {name for name in with_ef if not th.allclose(with_ef[name], without_ef[name], rtol=0, atol=1e-7)}
    assert changed == {name for name in with_ef if name.startswith("features_extractor.")}


@pytest.mark.parametrize("algorithm", HOSTS)
def test_ef_gradient_reaches_the_shared_encoder_rollout_and_decoder_only(algorithm):
    model = make(algorithm, grey_stack())
    model.learn(16)
    model.collect_rollouts(model.env, model._init_callback(None), model.rollout_buffer, model.n_steps)
    _, ef_loss, _ = model._ef_loss(model._rollout_windows()(np.arange(16)))
    model.policy.zero_grad()
    ef_loss.backward()
    reached = {name for name, p in model.policy.named_parameters() if p.grad is not None and p.grad.abs().sum() > 0}
    assert reached == {name for name, _ in model.policy.named_parameters() if name.startswith("features_extractor.")}
    for part in (model.ef.rollout_block, model.ef.decoder):
        assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in part.parameters())
    groups = {group.get("name"): group["params"] for group in model.policy.optimizer.param_groups}
    assert {id(p) for p in groups["auxiliary"]} == {id(p) for p in model.auxiliary.parameters()}


@pytest.mark.parametrize(
    ("env", "action_dim"),
    [(toy_env(discrete=True), 5), (grey_stack(), 6), (toy_env(), 2)],
)
def test_ef_reads_discrete_actions_one_hot(env, action_dim):
    assert make(PPOEF, env).ef.action_dim == action_dim


def test_babbling_rollouts_act_at_random_and_train_ef_alone():
    model = make(PPOEF, toy_env(), babbling_steps=8)
    model._setup_learn(16)
    heads = {name: p for name, p in parameters(model.policy).items() if not name.startswith("features_extractor.")}
    encoder, ef = parameters(model.policy.features_extractor), parameters(model.ef)
    model.collect_rollouts(model.env, model._init_callback(None), model.rollout_buffer, model.n_steps)
    assert model.babbling and set(np.unique(model.rollout_buffer.actions)) == {-1.0, 1.0}  # "sign" babbling
    model.train()
    after = parameters(model.policy)
    assert all(th.equal(after[name], value) for name, value in heads.items())
    assert all(not th.equal(after[f"features_extractor.{name}"], value) for name, value in encoder.items())
    assert all(not th.equal(value, ef[name]) for name, value in parameters(model.ef).items())
    model.collect_rollouts(model.env, model._init_callback(None), model.rollout_buffer, model.n_steps)
    assert not model.babbling  # num_timesteps reached babbling_steps: the policy acts (and trains) again
    model.learn(16)
    assert model.logger.name_to_value["rollout/babbling"] == 0.0


@pytest.mark.parametrize("algorithm", HOSTS)
def test_save_load_is_exact(algorithm, tmp_path):
    model = make(algorithm, toy_env(), babbling_steps=8)
    model.learn(32)
    model.beta = 0.5
    model.save(tmp_path / "model")
    loaded = algorithm.load(tmp_path / "model", env=toy_env(), device="cpu")
    saved, restored = model.get_parameters(), loaded.get_parameters()
    assert saved.keys() == restored.keys() == {"policy", "policy.optimizer", "auxiliary_module"}
    for name in ("policy", "auxiliary_module"):
        for key, value in saved[name].items():
            assert th.equal(value, restored[name][key]), (name, key)
    assert len(restored["policy.optimizer"]["param_groups"]) == 2
    states = saved["policy.optimizer"]["state"], restored["policy.optimizer"]["state"]  # Adam's or RMSprop's
    assert len(states[0]) == len(model.policy.optimizer.param_groups[1]["params"]) + len(
        list(model.policy.parameters())
    )
    for key, state in states[0].items():
        assert all(th.equal(value, states[1][key][name]) for name, value in state.items())
    assert (loaded.beta, loaded.auxiliary.beta, loaded.ef_horizon, loaded.agent_dim, loaded.frame_channels) == (
        0.5,
        0.5,
        3,
        8,
        3,
    )
    observations = np.stack([toy_env().observation_space.sample() for _ in range(3)])
    np.testing.assert_array_equal(
        loaded.predict(observations, deterministic=True)[0], model.predict(observations, deterministic=True)[0]
    )
    loaded.learn(16, reset_num_timesteps=False)
    assert loaded.num_timesteps == 48 and "train/ef_loss" in loaded.logger.name_to_value


def test_set_env_and_load_with_another_number_of_envs(tmp_path):
    """SB3's test_set_env, in part: the same number of envs to set_env, any number to load."""
    model = make(PPOEF, grey_stack(2))
    model.learn(16)
    model.set_env(grey_stack(2), force_reset=True)
    model.learn(16, reset_num_timesteps=False)
    assert model.num_timesteps == 32
    with pytest.raises(AssertionError):
        model.set_env(grey_stack(3))
    model.save(tmp_path / "model")
    loaded = PPOEF.load(tmp_path / "model", env=grey_stack(3))
    loaded.learn(24)
    assert loaded.num_timesteps == 24


def test_save_exclude_and_include(tmp_path):
    """SB3's test_exclude_include_saved_params."""
    model = make(A2CEF, toy_env(), verbose=2)
    model.save(tmp_path / "model", exclude=["verbose"])
    assert A2CEF.load(tmp_path / "model").verbose != 2
    model.save(tmp_path / "model", exclude=["verbose"], include=["verbose"])
    assert A2CEF.load(tmp_path / "model", custom_objects={"learning_rate": 2e-5}).learning_rate == 2e-5


@pytest.mark.parametrize("algorithm", HOSTS)
def test_policy_saved_alone_loads_into_sb3s_policy_class(algorithm, tmp_path):
    model = make(algorithm, toy_env()).learn(16)
    assert type(model.policy) is ActorCriticCnnPolicy  # EF is kept on the algorithm (model.auxiliary_module)
    model.policy.save(tmp_path / "policy.pt")
    loaded = ActorCriticCnnPolicy.load(tmp_path / "policy.pt")
    observations = np.stack([toy_env().observation_space.sample() for _ in range(4)])
    np.testing.assert_array_equal(
        loaded.predict(observations, deterministic=True)[0], model.policy.predict(observations, deterministic=True)[0]
    )


class ChannelsLast(gym.ObservationWrapper):
    """The toy world's frames as (height, width, 3 * frame_stack), the usual layout of image envs."""

    def __init__(self, env: gym.Env):
        super().__init__(env)
        channels, height, width = env.observation_space.shape
        self.observation_space = spaces.Box(0, 255, (height, width, channels), np.uint8)

    def observation(self, observation: np.ndarray) -> np.ndarray:
        return observation.transpose(1, 2, 0)


@pytest.mark.parametrize("discrete", [False, True])
def test_predict_single_and_vectorized_channels_last_observations(discrete):
    """SB3's test_predict: one observation or a batch, of an env SB3 transposes."""
    env = ChannelsLast(toy_env(discrete))
    model = make(PPOEF, env).learn(8)
    assert model.frame_shape == (3, 32, 32)
    observation, _ = env.reset(seed=0)
    action, _ = model.predict(observation, deterministic=True)
    assert env.action_space.contains(action)
    actions, _ = model.predict(np.stack([observation] * 3), deterministic=True)
    assert actions.shape == (3, *env.action_space.shape)
    with pytest.raises(ValueError, match=r"predict expects uint8 pixel observations"):
        model.predict(observation.astype(np.float32))


def test_atari_breakout_frames_train_ef_on_the_newest_grey_frame():
    ale_py = pytest.importorskip("ale_py")
    from stable_baselines3.common.env_util import make_atari_env

    gym.register_envs(ale_py)
    env = VecFrameStack(make_atari_env("BreakoutNoFrameskip-v4", n_envs=2, seed=0), 4)
    model = PPOEF(
        "CnnPolicy", env, n_steps=4, batch_size=8, n_epochs=1, seed=0, ef_horizon=3, ef_kwargs={"decoder_channels": 8}
    )
    assert (model.frame_shape, model.ef.action_dim, model.observation_space.shape) == ((1, 84, 84), 4, (4, 84, 84))
    model.learn(8)
    assert model.logger.name_to_value["train/ef_loss"] > 0
    env.close()


class VectorEnv(gym.Env):
    observation_space = spaces.Box(-1.0, 1.0, (4,), np.float32)
    action_space = spaces.Discrete(2)


class UnboundedActions(gym.ActionWrapper):
    def __init__(self, env: gym.Env):
        super().__init__(env)
        self.action_space = spaces.Box(-np.inf, np.inf, (2,), np.float32)

    def action(self, action: np.ndarray) -> np.ndarray:
        return action


@pytest.mark.parametrize(
    ("env", "kwargs", "message"),
    [
        (VectorEnv(), {}, r"PPOEF needs image observations: a uint8 Box"),
        (toy_env(), {"policy": "MultiInputPolicy"}, r"PPOEF: MultiInputPolicy reads Dict observations, got Box"),
        (toy_env(), {"ef_image_key": "pixels"}, r"PPOEF: ef_image_key='pixels' reads Dict observations, got Box"),
        (UnboundedActions(toy_env()), {}, r"encodes actions of a Box \(finite bounds\), Discrete, MultiDiscrete"),
        (toy_env(), {"ef_horizon": 33}, r"ef_horizon <= n_steps \* ef_rollouts = 8 \* 4, got ef_horizon=33"),
        (toy_env(), {"beta": 0.0}, r"use PPO to train without Ego-Foresight"),
        (toy_env(), {"agent_dim": 32}, r"feature_dim=32\), got 32"),
        (toy_env(), {"frame_channels": 2}, r"frame_channels must divide the observation's 9 channels, got 2"),
        (toy_env(), {"policy_kwargs": {**POLICY, "share_features_extractor": False}}, r"share_features_extractor"),
    ],
)
def test_bad_input_is_rejected_at_construction(env, kwargs, message):
    policy = kwargs.pop("policy", "CnnPolicy")
    with pytest.raises(ValueError, match=message):
        PPOEF(policy, env, **{"n_steps": 8, "batch_size": 8, "policy_kwargs": dict(POLICY), **EF, **kwargs})


def test_babbling_through_the_whole_run_is_refused():
    model = make(A2CEF, toy_env(), babbling_steps=16)
    with pytest.raises(ValueError, match=r"babbling_steps=16 must be below the 16 steps this learn call reaches"):
        model.learn(16)


def test_non_finite_ef_loss_raises_when_checked():
    model = make(PPOEF, toy_env(), check_finite_losses=True)
    with th.no_grad():
        next(model.ef.decoder.parameters()).fill_(float("nan"))
    with pytest.raises(ValueError, match=r"ef_loss is nan"):
        model.learn(8)


def test_caller_dicts_are_left_unchanged():
    policy_kwargs, ef_kwargs = dict(POLICY), deepcopy(EF["ef_kwargs"])
    make(PPOEF, toy_env(), policy_kwargs=policy_kwargs, ef_kwargs=ef_kwargs)
    assert policy_kwargs == POLICY and ef_kwargs == EF["ef_kwargs"]


def test_analyze_model_reads_a_ppo_ef_model_of_rgb_frames(tmp_path):
    """(Grey frames and discrete actions: tests/analysis/test_grey_discrete.py.)"""
    from sb3_ef.analysis.cli import analyze_model

    make(PPOEF, toy_env()).learn(8).save(tmp_path / "rgb.zip")
    written = analyze_model(str(tmp_path / "rgb.zip"), "toy/agent-v0", str(tmp_path / "rgb"), env_kwargs={})
    assert all(Path(path).is_file() for path in written.values())


@pytest.mark.parametrize("algorithm", HOSTS)
def test_a_ring_of_rollouts_gives_windows_longer_than_a_rollout(algorithm, tmp_path):
    model = make(
        algorithm,
        grey_stack(),
        n_steps=4,
        ef_horizon=6,
        ef_rollouts=3,
        **({"batch_size": 8} if algorithm is PPOEF else {}),
    )
    model.learn(40)  # five rollouts of 4 steps x 2 envs
    assert len(model._ef_ring.rollouts) == 3
    windows = model._ef_ring.windows(model._last_obs, model._last_episode_starts, 1, 6)
    mask = windows(np.arange(windows.size)).future_mask  # 3 rollouts x 4 steps x 2 envs
    assert mask.shape == (24, 6) and mask[:, 4].any()  # windows of 5 valid steps: past a rollout's 4
    model.save(tmp_path / "model")
    loaded = algorithm.load(tmp_path / "model", env=grey_stack())
    assert loaded.ef_rollouts == 3 and not loaded._ef_ring.rollouts  # rollouts are not saved, as SB3's buffer is not
    loaded.learn(8)


@pytest.mark.parametrize("algorithm", HOSTS)
def test_bf16_updates_stay_close_to_float32_and_the_option_is_saved(algorithm, tmp_path):
    """One rollout's update in bf16 against float32's from the same weights and data: losses within 5%, every
    logged value finite, the distribution heads' outputs float32; ``load`` keeps the option."""
    logs = {}
    for precision in ("fp32", "bf16"):
        model = make(algorithm, toy_env(), precision=precision, check_finite_losses=True)
        model.learn(8)
        logs[precision] = dict(model.logger.name_to_value)
        if precision == "bf16":
            features = model.policy.extract_features(th.zeros(2, 9, 32, 32, dtype=th.uint8))
            with autocast("bf16", model.device):
                assert model.policy.action_net(model.policy.mlp_extractor(features)[0]).dtype == th.float32
            model.save(tmp_path / "model.zip")
    assert algorithm.load(tmp_path / "model.zip", device="cpu").precision == "bf16"
    for key in ("train/ef_loss", "train/value_loss"):
        assert np.isfinite(logs["bf16"][key])
        assert logs["bf16"][key] == pytest.approx(logs["fp32"][key], rel=0.05), key


def test_latent_ef_predicts_the_features_of_grey_frame_stacks():
    ef_kwargs = {"target": "latent", "rollout_hidden_dims": (16,), "projection_dim": 8, "head_hidden_dim": 16}
    model = make(PPOEF, grey_stack(), ef_kwargs=ef_kwargs)
    model.learn(32)
    assert model.ef.target == "latent" and np.isfinite(model.logger.name_to_value["train/ef_loss"])


def test_setting_beta_checks_it_and_reaches_the_loss():
    model = make(A2CEF, toy_env())
    model.beta = 0.25
    assert (model.beta, float(model.auxiliary.beta)) == (0.25, 0.25)
    with pytest.raises(ValueError, match=r"beta must be a positive number \(use A2C to train without Ego-Foresight\)"):
        model.beta = 0.0
    assert model.beta == 0.25
