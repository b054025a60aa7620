"""CURL as an SB3 algorithm: the authors' defaults, one batch per update cropped as theirs, the update phases over
the whole run, exact save / load / resume, SB3's parameter tools, and named errors."""

from __future__ import annotations

import inspect

import numpy as np
import pytest
import torch as th
from stable_baselines3 import SAC
from stable_baselines3.common.torch_layers import NatureCNN
from stable_baselines3.sac.policies import MlpPolicy

from sb3_ef import CURL, SequenceReplayBuffer
from sb3_ef.common.buffers import SequenceReplayBufferSamples
from sb3_ef.common.saved_models import saved_data
from sb3_ef.curl import CURLActor, CURLEncoder, CURLLoss, CURLPolicy
from sb3_ef.envs.toy import ToyAgentEnv

SIZE, CROP = 40, 32
POLICY = {"net_arch": [32]}


def toy_env(size: int = SIZE) -> ToyAgentEnv:
    return ToyAgentEnv(size=size, max_episode_steps=20)


def make(**kwargs) -> CURL:
    arguments = {
        "crop_size": CROP,
        "features_dim": 16,
        "buffer_size": 300,
        "learning_starts": 12,
        "batch_size": 8,
        "policy_kwargs": dict(POLICY),
        "seed": 0,
        "device": "cpu",
    }
    return CURL("CnnPolicy", toy_env(), **{**arguments, **kwargs})


def test_defaults_are_the_authors():
    defaults = {name: p.default for name, p in inspect.signature(CURL).parameters.items()}
    assert {name: defaults[name] for name in ("learning_rate", "buffer_size", "learning_starts", "batch_size")} == {
        "learning_rate": 1e-3, "buffer_size": 100_000, "learning_starts": 1000, "batch_size": 128,
    }  # fmt: skip
    assert (defaults["tau"], defaults["target_update_interval"], defaults["actor_update_interval"]) == (0.01, 2, 2)
    assert (defaults["encoder_tau"], defaults["ent_coef"], defaults["crop_size"], defaults["features_dim"]) == (
        0.05, "auto_0.1", 84, 50,
    )  # fmt: skip
    assert (defaults["alpha_learning_rate"], defaults["alpha_beta"]) == (1e-4, 0.5)
    model = CURL("CnnPolicy", toy_env(100), buffer_size=200, device="cpu")
    assert isinstance(model, SAC) and isinstance(model.policy, CURLPolicy) and isinstance(model.actor, CURLActor)
    assert model.gamma == 0.99 and model.target_entropy == -2.0
    assert model.actor.latent_pi[0].out_features == model.critic.qf0[0].out_features == 1024
    for encoder in (model.critic.features_extractor, model.actor.features_extractor):
        assert isinstance(encoder, CURLEncoder) and (encoder.crop_size, encoder.features_dim) == (84, 50)
    assert model.policy.normalize_images is False
    assert type(model.replay_buffer) is SequenceReplayBuffer
    assert isinstance(model.auxiliary, CURLLoss)
    assert model.auxiliary.key_encoder is model.critic_target.features_extractor


def test_one_batch_per_update_its_anchor_crop_feeds_the_critic_the_actor_and_curl():
    model = make()
    model.learn(30)
    seen: dict[str, list[th.Tensor]] = {"critic": [], "actor": [], "target": []}
    modules = {"critic": model.critic.features_extractor, "actor": model.actor.features_extractor}
    modules["target"] = model.critic_target.features_extractor
    hooks = [
        module.register_forward_pre_hook(lambda _, inputs, name=name: seen[name].append(inputs[0].clone()))
        for name, module in modules.items()
    ]
    sampled: list[SequenceReplayBufferSamples] = []
    sample = model.replay_buffer.sample

    def recording_sample(*args, **kwargs):
        sampled.append(sample(*args, **kwargs))
        return sampled[-1]

    model.replay_buffer.sample = recording_sample
    assert model._n_updates % 2 == 0  # an update with the actor's step
    model.train(gradient_steps=1, batch_size=8)
    for hook in hooks:
        hook.remove()
    assert len(sampled) == 1 and sampled[0].observations.shape[-2:] == (SIZE, SIZE)
    # The critic encodes one crop three times (critic loss, actor loss, CURL's anchor), the actor that crop and the
    # next observations' crop, the critic target the next observations' crop and CURL's positive crop.
    anchor, next_crop, positive = seen["critic"][0], seen["target"][0], seen["target"][1]
    assert len(seen["critic"]) == 3 and all(th.equal(crop, anchor) for crop in seen["critic"])
    assert len(seen["actor"]) == 2 and th.equal(seen["actor"][0], next_crop) and th.equal(seen["actor"][1], anchor)
    assert len(seen["target"]) == 2 and not th.equal(anchor, positive)
    for crop in (anchor, next_crop, positive):
        assert crop.shape[-2:] == (CROP, CROP)
    frames, next_frames = sampled[0].observations, sampled[0].next_observations
    for crop, source in ((anchor, frames), (positive, frames), (next_crop, next_frames)):
        assert any(
            th.equal(crop[0], source[0, :, top : top + CROP, left : left + CROP])
            for top in range(SIZE - CROP)
            for left in range(SIZE - CROP)
        )


def test_actor_and_targets_move_every_second_update_counted_over_the_whole_run():
    model = make()
    model.learn(30)
    watched = {"actor": model.actor.latent_pi[0].weight, "target": model.critic_target.qf0[0].weight}
    watched["key encoder"] = model.auxiliary.key_encoder.projection[0].weight
    for _ in range(4):
        phase = model._n_updates % 2
        before = {name: value.detach().clone() for name, value in watched.items()}
        model.train(gradient_steps=1, batch_size=8)  # one update per call, as SB3 runs it
        moved = {name for name, value in watched.items() if not th.equal(before[name], value)}
        assert moved == (set(watched) if phase == 0 else set()), (model._n_updates, moved)


def test_training_logs_every_loss_and_moves_w():
    model = make()
    w = model.auxiliary.W.clone()
    model.learn(30)
    logged = model.logger.name_to_value
    for key in ("critic_loss", "actor_loss", "ent_coef", "ent_coef_loss", "curl_loss"):
        assert np.isfinite(logged[f"train/{key}"]), key
    assert logged["train/curl_loss"] > 0 and not th.equal(w, model.auxiliary.W)


def test_a_fixed_temperature_stays_fixed():
    model = make(ent_coef=0.05)
    model.learn(30)
    assert model.ent_coef_optimizer is None and model.logger.name_to_value["train/ent_coef"] == pytest.approx(0.05)


def test_save_load_is_exact_and_records_the_class(tmp_path):
    model = make()
    model.learn(31)
    model.save(tmp_path / "curl")
    assert saved_data(tmp_path / "curl.zip")["algorithm"] == "CURL"
    loaded = CURL.load(tmp_path / "curl", env=toy_env(), device="cpu", policy_kwargs=dict(POLICY))
    assert loaded.crop_size == CROP and loaded._n_updates == model._n_updates
    assert loaded.actor.features_extractor.convnet is loaded.critic.features_extractor.convnet
    assert loaded.auxiliary.key_encoder is loaded.critic_target.features_extractor
    for original, copy in ((model.policy, loaded.policy), (model.auxiliary, loaded.auxiliary)):
        saved, restored = original.state_dict(), copy.state_dict()
        assert saved.keys() == restored.keys() and all(th.equal(saved[name], restored[name]) for name in saved)
    observations = np.stack([toy_env().reset(seed=seed)[0] for seed in range(4)])
    assert np.array_equal(
        loaded.predict(observations, deterministic=True)[0], model.predict(observations, deterministic=True)[0]
    )
    assert th.equal(model._auxiliary_generator.get_state(), loaded._auxiliary_generator.get_state())  # the crops
    # The next update is the same: every optimiser's state, the temperature and the update phase came back.
    batch = model._crop(model.replay_buffer.sample(8))
    for algorithm in (model, loaded):
        th.manual_seed(3)
        algorithm._update(batch, step=algorithm._n_updates)
    for name, value in model.policy.state_dict().items():
        assert th.equal(value, loaded.policy.state_dict()[name]), name
    assert th.equal(model.auxiliary.W, loaded.auxiliary.W) and th.equal(model.log_ent_coef, loaded.log_ent_coef)
    loaded.learn(5, reset_num_timesteps=False)


def test_load_takes_the_constructors_policy_kwargs(tmp_path):
    policy_kwargs = {"net_arch": [32], "features_extractor_kwargs": {"n_filters": 8}}
    make(policy_kwargs=policy_kwargs).save(tmp_path / "curl")
    loaded = CURL.load(tmp_path / "curl", env=toy_env(), device="cpu", policy_kwargs=policy_kwargs)
    assert loaded.critic.features_extractor.convnet[0].out_channels == 8
    with pytest.raises(ValueError, match="policy kwargs do not equal the stored"):
        CURL.load(tmp_path / "curl", env=toy_env(), device="cpu", policy_kwargs={"net_arch": [64]})


def test_get_parameters_gives_tensor_state_dicts_that_set_parameters_takes_back():
    model = make()
    model.learn(20)
    parameters = model.get_parameters()
    for name in ("policy", "auxiliary_module"):
        assert parameters[name] and all(isinstance(value, th.Tensor) for value in parameters[name].values()), name
    other = make(seed=1)
    other.set_parameters(parameters, exact_match=True)
    assert th.equal(other.auxiliary.W, model.auxiliary.W)
    assert int(other.auxiliary.updates) == int(model.auxiliary.updates) > 0


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"crop_size": 48}, r"crop_size must be an int in \[1, 40\] \(at most the 40x40 frames.*got 48"),
        ({"encoder_tau": 0.0}, r"encoder_tau must be a number in \(0, 1\], got 0\.0"),
        ({"encoder_tau": "0.05"}, r"encoder_tau must be a number in \(0, 1\], got '0\.05'"),
        ({"actor_update_interval": 0}, r"actor_update_interval must be a positive int, got 0"),
        ({"target_update_interval": 1.5}, r"target_update_interval must be a positive int, got 1\.5"),
        ({"alpha_beta": 1.0}, r"alpha_beta must be a number \(the temperature's Adam beta1\) in \[0, 1\), got 1\.0"),
        ({"alpha_learning_rate": 0}, r"alpha_learning_rate must be a number > 0, got 0"),
        ({"policy_kwargs": {"features_extractor_class": NatureCNN}}, r"must be a CURLEncoder.*NatureCNN"),
        ({"policy_kwargs": {"normalize_images": True}}, r"normalize_images=False"),
        ({"policy_kwargs": {"share_features_extractor": True}}, r"share_features_extractor must be False"),
        ({"use_sde": True}, r"use_sde \(gSDE\) is not supported"),
        ({"shift_pad": 4}, r"augmentation is the random crop \(crop_size\): shift_pad is not a CURL argument"),
    ],
)
def test_bad_arguments_are_named(kwargs, message):
    with pytest.raises(ValueError, match=message):
        make(**kwargs)


def test_a_policy_for_vectors_is_refused():
    with pytest.raises(ValueError, match=r"CURL: unknown policy 'MlpPolicy'.*expected one of 'CnnPolicy'"):
        CURL("MlpPolicy", toy_env())
    with pytest.raises(ValueError, match=r"'CnnPolicy' or a CURLPolicy \(sub\)class, got SACPolicy"):
        CURL(MlpPolicy, toy_env())
