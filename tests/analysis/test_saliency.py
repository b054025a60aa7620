import time

import numpy as np
import pytest
import torch as th
from torch import nn

from sb3_ef.analysis.saliency import compute_saliency, decoder_saliency, saliency_overlay
from tests.helpers.analysis import REGION, SIZE, DotEnv, FakeForesight, FakeModel


def test_agent_map_is_zero_outside_the_region_h_a_drives():
    observation, _ = DotEnv().reset(seed=0)
    result = compute_saliency(observation, actions=np.ones((2, 2)), model=FakeModel())
    assert result.agent.shape == result.scene.shape == (SIZE, SIZE)
    assert result.frame.shape == (SIZE, SIZE, 3) and result.frame.dtype == np.uint8
    inside = np.zeros((SIZE, SIZE), dtype=bool)
    inside[:REGION, :REGION] = True
    assert np.all(result.agent[~inside] == 0) and np.all(result.agent[inside] > 0)
    assert np.all(result.scene[inside] == 0) and np.all(result.scene[~inside] > 0)
    assert result.agent.max() == pytest.approx(1.0) and result.scene.max() == pytest.approx(1.0)
    assert result.agent_patches.shape == (SIZE // 4, SIZE // 4)


def test_patch_norm_matches_a_single_backward_pass():
    ef = FakeForesight().eval()
    h_scene, h_agent = th.randn(1, 8, requires_grad=True), th.randn(1, 4, requires_grad=True)
    result = decoder_saliency(ef, h_scene, h_agent, patch_size=4, chunk_size=3)
    # scalar of patch (row 1, column 0): sum over channels of rows 4..7, columns 0..3 of the decoded frame
    ef.decode(h_scene, h_agent)[0, :, 4:8, 0:4].sum().backward()
    assert result.agent_patches[1, 0] == pytest.approx(h_agent.grad.norm().item(), rel=1e-5)
    assert result.scene_patches[1, 0] == pytest.approx(h_scene.grad.norm().item(), rel=1e-5, abs=1e-12)


def test_84x84_decoder_is_fast_enough():
    class Decoder(nn.Module):
        def __init__(self):
            super().__init__()
            self.net = nn.Sequential(
                nn.ConvTranspose2d(64, 16, 21, 1), nn.ReLU(), nn.ConvTranspose2d(16, 3, 4, 4), nn.Sigmoid()
            )

        def decode(self, h_scene, h_agent, skip=None):
            return self.net(th.cat([h_agent, h_scene], dim=1)[:, :, None, None])

    start = time.perf_counter()
    result = decoder_saliency(Decoder(), th.randn(1, 32), th.randn(1, 32))
    assert time.perf_counter() - start < 5.0
    assert result.agent.shape == (84, 84) and result.agent_patches.shape == (21, 21)


def test_bad_shapes_are_refused():
    ef = FakeForesight()
    with pytest.raises(ValueError, match=r"h_scene \(1, scene_dim\)"):
        decoder_saliency(ef, th.randn(2, 8), th.randn(2, 4))
    with pytest.raises(ValueError, match="not divisible by patch_size=5"):
        decoder_saliency(ef, th.randn(1, 8), th.randn(1, 4), patch_size=5)


def test_overlay_blends_colour_where_salient():
    frame = np.zeros((4, 4, 3), dtype=np.uint8)
    saliency = np.zeros((4, 4))
    saliency[0, 0] = 1.0
    overlay = saliency_overlay(frame, saliency, alpha=1.0, color=(0, 255, 0))
    assert overlay[0, 0].tolist() == [0, 255, 0] and overlay[1:].max() == 0
    with pytest.raises(ValueError, match="differ in size"):
        saliency_overlay(frame, np.zeros((3, 3)))
