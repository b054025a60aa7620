"""Loss coefficients live once, on the loss module: read and set through the model, saved with it, and files saved
before a coefficient was a buffer load with the value they were built with."""

from __future__ import annotations

import pytest
import torch as th

from sb3_ef import SACEF, SEAR, DrQv2EF
from sb3_ef.envs.toy import ToyAgentEnv
from tests.helpers.drqv2 import TINY_ALGO, TINY_POLICY, make_cue_env


def make(**kwargs) -> DrQv2EF:
    return DrQv2EF("CnnPolicy", make_cue_env(), policy_kwargs=TINY_POLICY, seed=0, device="cpu", **TINY_ALGO, **kwargs)


def test_beta_lives_on_the_loss_and_the_model_reads_and_sets_it_there(tmp_path):
    model = make(beta=0.7)
    assert "_beta" not in vars(model) and model.beta == pytest.approx(0.7)
    model.beta = 0.25
    assert float(model.auxiliary.beta) == 0.25
    observations, targets = model.auxiliary.prepare(model_batch(model), pad=0)
    features = model.encode(observations)
    weighted, logs = model.auxiliary(features, targets)
    th.testing.assert_close(weighted, 0.25 * logs["ef_loss"])
    model.save(tmp_path / "model.zip")
    assert DrQv2EF.load(tmp_path / "model.zip", device="cpu").beta == 0.25


def model_batch(model: DrQv2EF):
    model.learn(30)
    return model.replay_buffer.sample(2)


def test_a_state_saved_without_the_coefficient_loads_with_the_constructed_value():
    model = make(beta=0.5)
    state = {key: value for key, value in model.policy.state_dict().items() if key != "auxiliary.beta"}
    model.policy.auxiliary.beta.fill_(2.0)
    model.policy.load_state_dict(state)  # strict, as SB3's set_parameters
    assert model.beta == 2.0
    with pytest.raises(RuntimeError, match="Missing key"):
        model.policy.load_state_dict({k: v for k, v in state.items() if k != "actor.mu.0.weight"})


def test_sear_names_itself_for_an_ef_argument_and_keeps_its_weights_as_buffers():
    env = ToyAgentEnv(size=32, agent_masks=True)
    with pytest.raises(TypeError, match=r"SEAR takes no Ego-Foresight argument, got \['babbling_steps', 'beta'\]"):
        SEAR("CnnPolicy", env, beta=1.0, babbling_steps=10)
    model = SEAR("CnnPolicy", env, coefficients="efrl", policy_kwargs={"features_dim": 64}, device="cpu")
    assert {"auxiliary.reconstruction_coef", "auxiliary.mask_coef"} <= set(model.policy.state_dict())


@pytest.mark.parametrize("rate", [0.0, -1e-3, "fast", True])
def test_auxiliary_learning_rate_must_be_positive_or_none(rate):
    with pytest.raises(ValueError, match="auxiliary_learning_rate must be a positive number"):
        SACEF("CnnPolicy", make_cue_env(size=64), auxiliary_learning_rate=rate, buffer_size=100, device="cpu")
