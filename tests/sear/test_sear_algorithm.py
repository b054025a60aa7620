"""SEAR as an algorithm: DrQ-v2 with SEAR's decoders in the critic's Adam, the agent masks stored by its replay
buffer and shifted with their frames, exact save/load, where its gradients go, and named errors."""

from __future__ import annotations

import numpy as np
import pytest
import torch as th
from stable_baselines3.common.vec_env import DummyVecEnv

from sb3_ef import SEAR
from sb3_ef.envs.pixel_env import AGENT_MASKS_INFO_KEY
from sb3_ef.envs.toy import AGENT_COLOUR
from sb3_ef.envs.toy import AGENT_MASKS_INFO_KEY as TOY_KEY
from sb3_ef.sear import SEAR_LATENT_DIM, SEARLoss, SEARPolicy
from tests.helpers.sear import POLICY, SIZE, toy_env
from tests.helpers.sear import make_sear as make


def test_the_toy_env_gives_masks_under_the_pixel_envs_info_key():
    assert TOY_KEY == AGENT_MASKS_INFO_KEY
    env = toy_env()
    _, info = env.reset(seed=0)
    assert info[TOY_KEY].shape == (3, SIZE, SIZE) and np.array_equal(info[TOY_KEY][-1], env.agent_mask())
    _, _, _, _, info = env.step(np.ones(2))
    assert info[TOY_KEY].shape == (4, SIZE, SIZE) and np.array_equal(info[TOY_KEY][-1], env.agent_mask())
    assert not np.array_equal(info[TOY_KEY][-2], info[TOY_KEY][-1])  # the agent moved


def test_defaults_follow_sear_and_the_decoders_learn_in_the_critics_adam():
    model = SEAR("CnnPolicy", toy_env(), buffer_size=100, device="cpu")
    assert isinstance(model.policy, SEARPolicy) and model.policy.encoder.features_dim == SEAR_LATENT_DIM == 4096
    assert isinstance(model.auxiliary, SEARLoss)
    assert (model.auxiliary.reconstruction_coef, model.auxiliary.mask_coef) == (1.0, 0.25)
    assert model.replay_buffer.store_masks
    in_critic_adam = {id(p) for group in model.critic.optimizer.param_groups for p in group["params"]}
    assert {id(p) for p in model.auxiliary.parameters()} <= in_critic_adam
    assert {id(p) for p in model.policy.encoder.parameters()} <= in_critic_adam
    assert make(coefficients="efrl").auxiliary.mask_coef == 0.0025


def test_batches_carry_the_agent_masks_of_the_observations_frames():
    model = make(learning_starts=100)
    model.learn(40)
    batch = model.replay_buffer.sample(16)
    assert batch.masks is not None and batch.masks.shape == (16, 3, SIZE, SIZE)
    # The agent square is drawn on top in pure red: its mask is exactly the red pixels of each stacked frame.
    frames = batch.observations.unflatten(1, (3, 3))
    red = (frames == th.tensor(AGENT_COLOUR, dtype=th.uint8).view(1, 1, 3, 1, 1)).all(dim=2)
    assert th.equal(batch.masks.bool(), red)
    # One shift for frames and masks: after prepare the masks still cover the red pixels.
    observations, targets = model.auxiliary.prepare(batch, pad=4, generator=th.Generator().manual_seed(0))
    shifted = observations.unflatten(1, (3, 3)) == th.tensor(AGENT_COLOUR, dtype=th.uint8).view(1, 1, 3, 1, 1)
    assert th.equal(targets.masks.bool(), shifted.all(dim=2))
    assert not th.equal(observations, batch.observations)


def test_sear_updates_train_and_log_both_losses():
    model = make()
    decoder = [p.clone() for p in model.auxiliary.parameters()]
    model.learn(30)
    logs = model.logger.name_to_value
    assert logs["train/reconstruction_loss"] > 0 and logs["train/mask_loss"] > 0
    assert all(not th.equal(old, new) for old, new in zip(decoder, model.auxiliary.parameters(), strict=True))


def test_each_loss_reaches_its_half_of_the_latent_the_encoder_and_nothing_of_the_critic_or_actor():
    model = make(learning_starts=100)
    model.learn(30)
    batch = model.replay_buffer.sample(8)
    for coefficients, trained, untouched in (
        ((1.0, 0.0), model.auxiliary.frame_decoder, model.auxiliary.mask_decoder),
        ((0.0, 1.0), model.auxiliary.mask_decoder, model.auxiliary.frame_decoder),
    ):
        model.policy.zero_grad(set_to_none=True)
        model.auxiliary.reconstruction_coef.fill_(coefficients[0])
        model.auxiliary.mask_coef.fill_(coefficients[1])
        observations, targets = model._augment_observations(batch, pad=4)
        features = model.policy.encoder(observations)
        features.retain_grad()
        model.auxiliary(features, targets)[0].backward()
        half = model.auxiliary.features_dim // 2
        reached, other = (features.grad[:, :half], features.grad[:, half:])
        if coefficients[1]:
            reached, other = other, reached
        assert reached.abs().sum() > 0 and other.abs().sum() == 0
        assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in trained.parameters())
        assert all(p.grad is None or p.grad.abs().sum() == 0 for p in untouched.parameters())
        assert all(p.grad is not None for p in model.policy.encoder.parameters())
        assert all(p.grad is None for p in [*model.critic.parameters(), *model.actor.parameters()])


def test_save_load_is_exact(tmp_path):
    model = make(coefficients=(0.5, 0.125))
    model.learn(30)
    model.save(tmp_path / "sear")
    loaded = SEAR.load(tmp_path / "sear", env=toy_env(), device="cpu")
    assert (loaded.auxiliary.reconstruction_coef, loaded.auxiliary.mask_coef) == (0.5, 0.125)
    saved, restored = model.policy.state_dict(), loaded.policy.state_dict()
    assert saved.keys() == restored.keys() and any(name.startswith("auxiliary.") for name in saved)
    assert all(th.equal(saved[name], restored[name]) for name in saved)
    observations = np.stack([toy_env().reset(seed=seed)[0] for seed in range(4)])
    assert np.array_equal(
        loaded.predict(observations, deterministic=True)[0], model.predict(observations, deterministic=True)[0]
    )
    with th.no_grad():
        encoded = model.policy.encoder(th.as_tensor(observations))
        assert all(
            th.equal(a, b)
            for a, b in zip(model.auxiliary.decode(encoded), loaded.auxiliary.decode(encoded), strict=True)
        )
    loaded.learn(5, reset_num_timesteps=False)


def test_an_env_without_masks_is_refused_at_construction_and_in_set_env():
    with pytest.raises(ValueError, match=r"make_env\(\.\.\., agent_masks=True\).*agent_masks are \[False\]"):
        SEAR("CnnPolicy", toy_env(agent_masks=False), device="cpu")
    model = make()
    with pytest.raises(ValueError, match=r"make_env\(\.\.\., agent_masks=True\)"):
        model.set_env(DummyVecEnv([lambda: toy_env(agent_masks=False)]))


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"coefficients": "sera"}, r"Unknown SEAR coefficient preset 'sera'.*\['efrl', 'sear'\]"),
        ({"coefficients": (1.0, -0.5)}, r"pair of non-negative numbers.*\(1\.0, -0\.5\)"),
        ({"coefficients": (1.0,)}, r"pair of non-negative numbers"),
        ({"replay_buffer_kwargs": {"store_masks": False}}, r"must not set store_masks to False"),
        ({"policy_kwargs": {**POLICY, "features_dim": 63}}, r"features_dim must be an even int >= 2, got 63"),
    ],
)
def test_bad_arguments_are_named(kwargs, message):
    with pytest.raises(ValueError, match=message):
        make(**kwargs)
