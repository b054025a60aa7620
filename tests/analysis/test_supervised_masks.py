"""SEAR's decoded agent masks for the notebook's side-by-side with EF's saliency."""

from __future__ import annotations

import numpy as np
import pytest
import torch as th

from sb3_ef import DrQv2
from sb3_ef.analysis.supervised_masks import decoded_agent_masks
from tests.helpers.sear import POLICY, SIZE, make_sear, toy_env

# a larger batch and buffer than the SEAR tests' default, so that 2000 steps teach the mask decoder the agent
MASK_TRAINING = {"buffer_size": 400, "learning_starts": 16, "batch_size": 16}


def test_decoded_masks_are_the_mask_decoders_sigmoid_on_the_second_half_of_the_features():
    model = make_sear(**MASK_TRAINING)
    observation, _ = toy_env().reset(seed=0)
    masks = decoded_agent_masks(model, observation)
    assert masks.shape == (3, SIZE, SIZE) and masks.dtype == np.float32
    with th.no_grad():
        features = model.policy.encode(th.as_tensor(observation).unsqueeze(0))
        expected = th.sigmoid(model.auxiliary.mask_decoder(features[:, POLICY["features_dim"] // 2 :]))[0]
    np.testing.assert_allclose(masks, expected.numpy(), rtol=1e-6, atol=1e-7)
    assert model.policy.training == model.auxiliary.training  # the modes it found are restored


@pytest.mark.slow
def test_a_trained_sear_gives_the_toy_agents_pixels_a_higher_probability_than_the_background():
    env = toy_env()
    observation, _ = env.reset(seed=3)
    for _ in range(4):
        observation, *_ = env.step(np.ones(2, dtype=np.float32))
    agent = env.agent_mask().astype(bool)
    untrained = make_sear(**MASK_TRAINING)
    trained = make_sear(**MASK_TRAINING)
    trained.learn(2000)
    contrast = {}
    for name, model in (("untrained", untrained), ("trained", trained)):
        probability = decoded_agent_masks(model, observation)[-1]
        contrast[name] = probability[agent].mean() / probability[~agent].mean()
    assert contrast["trained"] > 2.0, contrast  # about 4 after 2000 steps
    assert contrast["untrained"] < 1.2, contrast  # about 1: the untrained decoder does not know the agent


def test_refuses_a_model_without_a_mask_decoder_and_an_observation_of_another_shape():
    with pytest.raises(TypeError, match="Expected a SEAR model"):
        decoded_agent_masks(DrQv2("CnnPolicy", toy_env(agent_masks=False), buffer_size=100, device="cpu"), None)
    with pytest.raises(ValueError, match=r"trained on observations of shape \(9, 32, 32\), got \(9, 16, 16\)"):
        decoded_agent_masks(make_sear(**MASK_TRAINING), np.zeros((9, 16, 16), dtype=np.uint8))
