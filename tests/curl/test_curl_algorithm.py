"""CURL as an algorithm: SB3's SAC on random crops with CURLEncoder, CURL's step on the critic's encoder and W only,
the key encoder following at the critic target's pace, exact save/load, and named errors."""

from __future__ import annotations

import numpy as np
import pytest
import torch as th
from stable_baselines3 import SAC
from stable_baselines3.common.torch_layers import NatureCNN

from sb3_ef import CURL, SequenceReplayBuffer
from sb3_ef.curl import CroppedSequenceReplayBuffer, CURLEncoder, CURLLoss
from sb3_ef.envs.toy import ToyAgentEnv

SIZE, CROP = 40, 32


def toy_env(size: int = SIZE) -> ToyAgentEnv:
    return ToyAgentEnv(size=size, max_episode_steps=20)


def make(**kwargs) -> CURL:
    arguments = {
        "crop_size": CROP,
        "features_dim": 16,
        "buffer_size": 300,
        "learning_starts": 12,
        "batch_size": 8,
        "policy_kwargs": {"net_arch": [32]},
        "seed": 0,
        "device": "cpu",
    }
    return CURL("CnnPolicy", toy_env(), **{**arguments, **kwargs})


def test_curl_is_sac_with_curl_encoders_and_a_cropping_buffer():
    model = make(target_update_interval=2, encoder_tau=0.1)
    assert isinstance(model, SAC)
    for encoder in (model.critic.features_extractor, model.actor.features_extractor):
        assert isinstance(encoder, CURLEncoder) and encoder.crop_size == CROP and encoder.features_dim == 16
    assert model.policy.normalize_images is False
    assert isinstance(model.replay_buffer, CroppedSequenceReplayBuffer) and model.replay_buffer.crop_size == CROP
    assert isinstance(model.auxiliary, CURLLoss)
    assert (model.auxiliary.encoder_tau, model.auxiliary.key_update_interval) == (0.1, 2)
    optimised = {id(p) for group in model.auxiliary_optimizer.param_groups for p in group["params"]}
    assert id(model.auxiliary.W) in optimised
    assert {id(p) for p in model.critic.features_extractor.parameters()} <= optimised
    assert all(not p.requires_grad for p in model.auxiliary.key_encoder.parameters())


def test_sacs_updates_see_random_crops_and_curls_step_whole_frames():
    model = make(learning_starts=100)
    model.learn(30)
    seen: list[tuple[int, ...]] = []
    hooks = [
        module.register_forward_pre_hook(lambda _, inputs: seen.append(tuple(inputs[0].shape[-2:])))
        for module in (model.critic.features_extractor, model.actor.features_extractor)
    ]
    sampled: list[tuple[int, ...]] = []
    sample = model.replay_buffer.sample

    def recording_sample(*args, **kwargs):
        batch = sample(*args, **kwargs)
        sampled.append(tuple(batch.observations.shape[-2:]))
        return batch

    model.replay_buffer.sample = recording_sample  # type: ignore[method-assign]
    model.train(gradient_steps=2, batch_size=8)
    for hook in hooks:
        hook.remove()
    assert seen and set(seen) == {(CROP, CROP)}  # SAC's encoders never centre-crop a whole frame in training
    assert sampled == [(CROP, CROP)] * 2 + [(SIZE, SIZE)] * 2  # SAC's two batches, then CURL's two
    whole = model.replay_buffer.sample(4)
    with model.replay_buffer.cropping():
        cropped = model.replay_buffer.sample(4)
    assert whole.observations.shape[-2:] == (SIZE, SIZE) and cropped.observations.shape[-2:] == (CROP, CROP)
    assert cropped.next_observations.shape[-2:] == (CROP, CROP)


def test_curl_loss_reaches_the_critic_encoder_and_w_only():
    model = make(learning_starts=100)
    model.learn(30)
    batch = model.replay_buffer.sample(8)
    observations, keys = model._augment_observations(batch, pad=0)
    assert observations.shape[-2:] == keys.shape[-2:] == (CROP, CROP)
    model.auxiliary(model.encode(observations), keys)[0].backward()
    encoder = set(model.critic.features_extractor.parameters())
    for parameter in model.policy.parameters():
        reached = parameter.grad is not None and parameter.grad.abs().sum() > 0
        assert reached == (parameter in encoder)
    assert model.auxiliary.W.grad is not None and model.auxiliary.W.grad.abs().sum() > 0
    assert all(p.grad is None for p in model.auxiliary.key_encoder.parameters())


def test_the_key_encoder_follows_every_target_update_interval_steps():
    model = make(target_update_interval=2, learning_starts=100)
    model.learn(30)
    key = model.auxiliary.key_encoder
    before = [p.clone() for p in key.parameters()]
    model.train(gradient_steps=1, batch_size=8)
    assert all(th.equal(old, new) for old, new in zip(before, key.parameters(), strict=True))
    model.train(gradient_steps=1, batch_size=8)
    online = model.critic.features_extractor.parameters()
    for old, new, target in zip(before, key.parameters(), online, strict=True):
        assert th.allclose(new, 0.95 * old + 0.05 * target, atol=1e-6)


def test_training_logs_the_curl_loss_and_moves_w():
    model = make()
    w = model.auxiliary.W.clone()
    model.learn(30)
    assert model.logger.name_to_value["train/curl_loss"] > 0
    assert not th.equal(w, model.auxiliary.W)


def test_save_load_is_exact(tmp_path):
    model = make(target_update_interval=2)
    model.learn(31)
    model.save(tmp_path / "curl")
    loaded = CURL.load(tmp_path / "curl", env=toy_env(), device="cpu")
    assert isinstance(loaded.replay_buffer, CroppedSequenceReplayBuffer) and loaded.crop_size == CROP
    for original, copy in ((model.policy, loaded.policy), (model.auxiliary, loaded.auxiliary)):
        saved, restored = original.state_dict(), copy.state_dict()
        assert saved.keys() == restored.keys()
        assert all(th.equal(saved[name], restored[name]) for name in saved if isinstance(saved[name], th.Tensor))
    assert loaded.auxiliary._updates == model.auxiliary._updates > 0
    assert loaded.auxiliary.key_update_interval == 2
    observations = np.stack([toy_env().reset(seed=seed)[0] for seed in range(4)])
    assert np.array_equal(
        loaded.predict(observations, deterministic=True)[0], model.predict(observations, deterministic=True)[0]
    )
    loaded.learn(5, reset_num_timesteps=False)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"crop_size": 48}, r"crop_size must be an int in \[1, 40\] \(at most the 40x40 frames.*got 48"),
        ({"encoder_tau": 0.0}, r"encoder_tau must be in \(0, 1\], got 0\.0"),
        ({"replay_buffer_class": SequenceReplayBuffer}, r"must be a CroppedSequenceReplayBuffer.*SequenceReplayBuffer"),
        ({"policy_kwargs": {"features_extractor_class": NatureCNN}}, r"must be a CURLEncoder.*NatureCNN"),
        ({"policy_kwargs": {"normalize_images": True}}, r"normalize_images=False"),
    ],
)
def test_bad_arguments_are_named(kwargs, message):
    with pytest.raises(ValueError, match=message):
        make(**kwargs)
