"""SAC-EF, TD3-EF and TQC-EF: EF's step trains the critic's encoder and nothing else of the host's."""

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from stable_baselines3 import SAC, TD3
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.monitor import Monitor

from sb3_ef import SACEF, TD3EF, TQCEF
from sb3_ef.common.buffers import SequenceReplayBuffer
from sb3_ef.drqv2.policies import DrQv2Encoder
from sb3_ef.envs.toy import ToyAgentEnv
from tests.helpers.learning import random_return

HOSTS = [SACEF, TD3EF, TQCEF]
LEARNING_STARTS = 12
# A small CNN for 32x32 frames (SB3's NatureCNN needs 36x36 and more); it scales the pixels itself.
POLICY = {
    "net_arch": [16],
    "normalize_images": False,
    "features_extractor_class": DrQv2Encoder,
    "features_extractor_kwargs": {"features_dim": 32},
}
EF = {"ef_horizon": 3, "agent_dim": 8, "ef_kwargs": {"rollout_hidden_dims": (16,), "decoder_channels": 8}}


def toy_env(**kwargs) -> ToyAgentEnv:
    return ToyAgentEnv(size=32, max_episode_steps=20, **kwargs)


def make(algorithm, **kwargs):
    arguments = {"buffer_size": 300, "learning_starts": LEARNING_STARTS, "batch_size": 8, "seed": 0}
    arguments["policy_kwargs"] = dict(POLICY)  # SB3 writes into the dict it is given
    if algorithm in HOSTS:
        arguments.update(EF)
    if algorithm in (SAC, TD3):
        arguments.update(replay_buffer_class=SequenceReplayBuffer, replay_buffer_kwargs={"horizon": 3})
    arguments.update(kwargs)
    return algorithm("CnnPolicy", toy_env(), **arguments)


def named_parameters(model) -> dict[str, th.Tensor]:
    """Every parameter of the host's networks (EF's excluded), by name."""
    return {name: p for name, p in model.policy.named_parameters() if not name.startswith("auxiliary.")}


@pytest.mark.parametrize("algorithm", HOSTS)
def test_ef_gradient_reaches_the_critic_encoder_and_nothing_else_of_the_hosts(algorithm):
    model = make(algorithm, learning_starts=100)
    model.learn(30)
    batch = model.replay_buffer.sample(8)
    observations, window = model._augment_observations(batch, pad=model.shift_pad)
    model.auxiliary(model.encode(observations), window)[0].backward()
    reached = {name for name, p in named_parameters(model).items() if p.grad is not None and p.grad.abs().sum() > 0}
    encoder = {f"critic.features_extractor.{name}" for name, _ in model.critic.features_extractor.named_parameters()}
    assert reached == encoder
    assert all(p.grad is not None for p in model.ef.parameters())


@pytest.mark.parametrize(("algorithm", "host"), [(SACEF, SAC), (TD3EF, TD3)])
def test_host_update_is_unchanged_and_ef_step_moves_only_the_critic_encoder(algorithm, host):
    models = []
    for variant in (algorithm, host):  # each built (seeding the global generators) right before it learns
        models.append(make(variant).learn(LEARNING_STARTS + 1))  # one host update, then (with EF) one EF step
    logged = [model.logger.name_to_value for model in models]
    assert "train/ef_loss" in logged[0] and "train/ef_loss" not in logged[1]
    for key in ("train/critic_loss", "train/actor_loss"):
        assert logged[0][key] == logged[1][key]
    with_ef, without_ef = (named_parameters(model) for model in models)
    assert with_ef.keys() == without_ef.keys()
    changed = {name for name in with_ef if not th.equal(with_ef[name], without_ef[name])}
    assert changed and all(name.startswith("critic.features_extractor.") for name in changed)


@pytest.mark.parametrize("algorithm", HOSTS)
def test_save_load_is_exact(algorithm, tmp_path):
    model = make(algorithm, babbling_steps=15)
    model.learn(20)
    model.save(tmp_path / "model")
    loaded = algorithm.load(tmp_path / "model", env=toy_env())
    for (name, a), b in zip(model.policy.state_dict().items(), loaded.policy.state_dict().values(), strict=True):
        assert th.equal(a, b), name
    saved, restored = model.auxiliary_optimizer.state_dict()["state"], loaded.auxiliary_optimizer.state_dict()["state"]
    assert saved.keys() == restored.keys() and len(saved) > 0
    assert all(th.equal(saved[k]["exp_avg"], restored[k]["exp_avg"]) for k in saved)
    assert (loaded.beta, loaded.ef_horizon, loaded.agent_dim, loaded.babbling_steps) == (1.0, 3, 8, 15)
    observations = np.stack([toy_env().observation_space.sample() for _ in range(3)])
    np.testing.assert_array_equal(
        loaded.predict(observations, deterministic=True)[0], model.predict(observations, deterministic=True)[0]
    )
    loaded.learn(5, reset_num_timesteps=False)
    assert "train/ef_loss" in loaded.logger.name_to_value


def test_caller_dicts_are_left_unchanged_and_the_buffer_is_a_sequence_buffer():
    policy_kwargs = dict(POLICY)
    model = make(SACEF, policy_kwargs=policy_kwargs)
    assert policy_kwargs == POLICY
    assert isinstance(model.replay_buffer, SequenceReplayBuffer) and model.replay_buffer.horizon == 3
    assert model.frame_shape == (3, 32, 32) and model.encode(th.zeros(2, 9, 32, 32, dtype=th.uint8)).shape == (2, 32)


class VectorEnv(gym.Env):
    observation_space = spaces.Box(-1.0, 1.0, (4,), np.float32)
    action_space = spaces.Box(-1.0, 1.0, (1,), np.float32)


@pytest.mark.parametrize(
    ("env", "kwargs", "message"),
    [
        (VectorEnv(), {}, r"SACEF expects stacked RGB frames"),
        (toy_env(), {"replay_buffer_class": ReplayBuffer}, r"SequenceReplayBuffer .*got ReplayBuffer"),
        (toy_env(), {"beta": 0.0}, r"use SAC to train without Ego-Foresight"),
        (ToyAgentEnv(size=32, max_episode_steps=2), {}, r"expected ef_horizon <= 2, got 3"),
        (toy_env(), {"agent_dim": 32}, r"agent_dim must be in \[1, feature_dim=32\), got 32"),
    ],
)
def test_bad_input_is_rejected_at_construction(env, kwargs, message):
    with pytest.raises(ValueError, match=message):
        SACEF("CnnPolicy", env, **{"buffer_size": 100, "policy_kwargs": POLICY, **EF, **kwargs})


def test_non_finite_ef_loss_raises_when_checked():
    model = make(SACEF, check_finite_losses=True)
    with th.no_grad():
        next(model.ef.decoder.parameters()).fill_(float("nan"))
    with pytest.raises(ValueError, match=r"ef_loss is nan at update 1"):
        model.learn(LEARNING_STARTS + 1)


@pytest.mark.slow
def test_sac_ef_learns_to_bring_the_agent_to_the_centre():
    """Reward: minus the agent's distance to the frame centre, so the policy must find the red square in the image.
    Random actions earn about -6 per 20-step episode; SAC-EF after 1000 steps about -1 (~9 min on 2 loaded cores)."""
    policy = {**POLICY, "net_arch": [64, 64], "features_extractor_kwargs": {"features_dim": 64}}
    model = SACEF(
        "CnnPolicy", toy_env(), buffer_size=5000, learning_starts=100, batch_size=32, learning_rate=1e-3,
        ent_coef=0.01, policy_kwargs=policy, ef_horizon=3, agent_dim=8, babbling_steps=100,
        ef_kwargs={"rollout_hidden_dims": (32,), "decoder_channels": 16}, seed=0,
    )  # fmt: skip
    model.learn(1000)
    trained, _ = evaluate_policy(model, Monitor(toy_env()), n_eval_episodes=20)
    baseline = random_return(toy_env(), 20)
    assert baseline < -4.0
    assert trained > baseline + 2.5
