import imageio.v2 as imageio
import numpy as np
import pytest
import torch as th
from PIL import Image

from sb3_ef.analysis.prediction import (
    context_frames,
    figure_eight_actions,
    predict_open_loop,
    save_prediction_grid,
    save_video,
)
from sb3_ef.ef import EgoForesight
from tests.helpers.analysis import SIZE, DotEnv, FakeModel


def test_prediction_matches_ef_predict_and_restores_training_mode():
    model = FakeModel()
    observation, _ = DotEnv().reset(seed=1)
    actions = figure_eight_actions(7, 2)
    model.ef.train()
    frames = predict_open_loop(observation, actions, model=model)
    assert frames.shape == (7, SIZE, SIZE, 3) and frames.dtype == np.uint8
    assert model.ef.training
    model.ef.eval()
    with th.no_grad():
        h = model.encode(th.as_tensor(observation)[None])
        expected = model.ef.predict(h, th.as_tensor(actions)[None])[0].permute(0, 2, 3, 1)
    np.testing.assert_allclose(frames, (expected * 255).round().numpy(), atol=1)


def test_real_ego_foresight_beyond_its_horizon_with_an_explicit_encoder():
    ef = EgoForesight(feature_dim=40, action_dim=3, frame_shape=(3, 16, 16), agent_dim=8, horizon=2,
                      rollout_hidden_dims=(16,), decoder_channels=8)  # fmt: skip
    encoder = th.nn.Sequential(th.nn.Flatten(), th.nn.LazyLinear(40))
    observation = np.random.default_rng(0).integers(0, 256, (9, 16, 16), dtype=np.uint8)
    encode = lambda obs: encoder(obs.float() / 255 - 0.5)  # noqa: E731
    frames = predict_open_loop(observation, figure_eight_actions(5, 3), encoder=encode, ef=ef)
    assert frames.shape == (5, 16, 16, 3)
    # the h_a rollout changes the prediction from step to step
    assert not np.array_equal(frames[0], frames[-1])
    with pytest.raises(ValueError, match="Expected actions with 3 dimensions, got 2"):
        predict_open_loop(observation, np.zeros((4, 2)), encoder=encode, ef=ef)
    with pytest.raises(ValueError, match="Expected one stacked uint8 observation"):
        predict_open_loop(observation.astype(np.float32), np.zeros((4, 3)), encoder=encode, ef=ef)
    with pytest.raises(ValueError, match="either a model or encoder"):
        predict_open_loop(observation, np.zeros((4, 3)), model=FakeModel(), ef=ef)


def test_figure_eight_is_a_closed_bounded_path_padded_with_zeros():
    actions = figure_eight_actions(40, 4, period=40)
    assert actions.shape == (40, 4) and np.abs(actions).max() <= 1.0
    assert np.all(actions[:, 2:] == 0)
    positions = np.cumsum(actions[:, :2], axis=0)
    assert np.allclose(positions[-1], 0.0, atol=1e-4)  # back at the start after one period
    with pytest.raises(ValueError, match="at least 1 dimension, got 0"):
        figure_eight_actions(10, 0)


def test_figure_eight_on_one_action_dimension_swings_back_and_forth():
    """Cartpole has one actuator: the probe is the figure eight's first component alone."""
    actions = figure_eight_actions(40, 1, period=40)
    assert actions.shape == (40, 1)
    assert np.array_equal(actions[:, 0], figure_eight_actions(40, 2, period=40)[:, 0])
    assert actions.max() == 1.0 and actions.min() < -0.99


def test_grid_png_and_videos_are_written(tmp_path):
    observation, _ = DotEnv().reset(seed=0)
    context = context_frames(observation)
    assert context.shape == (3, SIZE, SIZE, 3)
    predicted = np.arange(4, dtype=np.uint8)[:, None, None, None] * np.full((4, SIZE, SIZE, 3), 50, np.uint8)
    true = np.full((4, SIZE, SIZE, 3), 255, dtype=np.uint8)
    grid = Image.open(save_prediction_grid(tmp_path / "grid.png", context, predicted, true))
    assert grid.size == (4 * SIZE + 6, 3 * SIZE + 4)
    gif = imageio.mimread(save_video(tmp_path / "out" / "prediction.gif", predicted, true))
    assert len(gif) == 4 and gif[0].shape[:2] == (SIZE, 2 * SIZE)
    save_video(tmp_path / "p.mp4", predicted)
    assert (tmp_path / "p.mp4").stat().st_size > 0
    with pytest.raises(ValueError, match=r"\.gif or \.mp4"):
        save_video(tmp_path / "p.avi", predicted)
