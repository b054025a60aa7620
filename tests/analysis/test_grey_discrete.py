"""The analysis of PPO-EF / A2C-EF on Atari: 4 stacked grey 84x84 frames (SB3's make_atari_env + VecFrameStack),
Discrete actions."""

import json

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from PIL import Image
from stable_baselines3.common.logger import configure
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from sb3_ef import A2CEF, PPOEF
from sb3_ef.analysis.callbacks import ForesightLoggerCallback
from sb3_ef.analysis.cli import atari_env, main
from sb3_ef.analysis.prediction import action_batch, predict_open_loop
from sb3_ef.analysis.report import foresight_report, record_rollout
from sb3_ef.analysis.saliency import compute_saliency

ale_py = pytest.importorskip("ale_py")
GAME = "PongNoFrameskip-v4"
TINY = {
    "n_steps": 16, "ef_horizon": 3, "ef_rollouts": 1, "agent_dim": 8, "device": "cpu", "seed": 0,
    "ef_kwargs": {"rollout_hidden_dims": (16,), "decoder_channels": 8},
    "policy_kwargs": {"features_extractor_kwargs": {"features_dim": 64}},
}  # fmt: skip


def atari_training_env():
    from stable_baselines3.common.env_util import make_atari_env
    from stable_baselines3.common.vec_env import VecFrameStack

    gym.register_envs(ale_py)
    return VecFrameStack(make_atari_env(GAME, n_envs=1, seed=0), n_stack=4)


@pytest.fixture(scope="module")
def pong(tmp_path_factory):
    """A PPO-EF trained one rollout on Pong, saved."""
    model = PPOEF("CnnPolicy", atari_training_env(), batch_size=16, n_epochs=1, **TINY)
    model.learn(16)
    path = tmp_path_factory.mktemp("pong") / "ppo_ef.zip"
    model.save(path)
    return model, path


def test_the_analysis_env_gives_the_observations_the_model_trained_on():
    from stable_baselines3.common.vec_env import VecTransposeImage

    training = VecTransposeImage(atari_training_env())
    analysis = atari_env(GAME, 84, 4)
    observation, _ = analysis.reset(seed=0)
    assert analysis.observation_space.shape == training.observation_space.shape == (4, 84, 84)
    assert np.array_equal(observation, training.reset()[0])
    for action in (1, 2, 3, 2):
        observation = analysis.step(action)[0]
        assert np.array_equal(observation, training.step(np.array([action]))[0][0])


def test_grey_frames_and_discrete_actions_are_predicted_and_scored(pong):
    model, _ = pong
    env = atari_env(GAME, 84, 4)
    rollout = record_rollout(env, lambda _obs, step: step % 6, 4, seed=0, frame_channels=1)
    assert rollout.actions.shape == (4, 1) and rollout.true_frames.shape == (4, 84, 84, 1)
    predicted = predict_open_loop(rollout.first_observation, rollout.actions, model=model)
    assert predicted.shape == (4, 84, 84, 1) and predicted.dtype == np.uint8
    saliency = compute_saliency(rollout.first_observation, rollout.actions, model=model)
    assert saliency.frame.shape == (84, 84, 1) and saliency.agent.shape == saliency.scene.shape == (84, 84)
    report = foresight_report(model, rollout)
    assert np.array_equal(report.predicted, predicted)
    assert set(report.scalars()) == {"prediction_mse"}  # Atari has no agent mask
    # drawn in grey: rows of 4 context, 4 predicted, 4 true frames, each pixel's three channels equal
    image = report.prediction_image()
    assert image.shape == (3 * 84 + 4, 4 * 84 + 6, 3) and np.array_equal(image[..., 0], image[..., 2])
    assert report.saliency_image().shape == (84, 3 * 84 + 4, 3)
    with pytest.raises(ValueError, match="frames have 3 channels, the model predicts frames of 1"):
        foresight_report(model, record_rollout(env, lambda *_: 0, 2, seed=0))  # frame_channels left at RGB's 3


def test_the_env_actions_are_encoded_as_the_host_encodes_them(pong):
    model, _ = pong
    host = model._ef_ring.rollouts[-1][1][:, 0]  # (n_steps, 6): what EF trained on
    played = model.rollout_buffer.actions  # the env's actions, as SB3's rollout buffer keeps them
    assert th.equal(action_batch(played, model.ef, th.device("cpu"), model.action_space)[0], host)
    one_hot = action_batch(np.array([2, 0, 5]), model.ef, th.device("cpu"), model.action_space)
    assert th.equal(one_hot[0], th.eye(6)[[2, 0, 5]])
    with pytest.raises(ValueError, match=r"Expected \(steps, 1\) actions of Discrete\(6\), got shape \(3, 2\)"):
        action_batch(np.zeros((3, 2)), model.ef, th.device("cpu"), model.action_space)


def test_analyze_model_on_a_saved_ppo_ef_pong_model(pong, tmp_path, capsys):
    _, path = pong
    out = tmp_path / "analysis"
    assert main(["model", str(path), "--env", GAME, "--steps", "3", "--out", str(out)]) == 0
    assert f"Wrote prediction.png, prediction.gif, saliency.png, scores.json to {out}" in capsys.readouterr().out
    assert Image.open(out / "prediction.png").size > (4 * 84 + 6, 3 * 84 + 4)
    scores = json.loads((out / "scores.json").read_text())
    assert scores["steps"] == 3 and scores["actions"] == "policy"
    assert set(scores) == {"env", "env_kwargs", "steps", "actions", "prediction_mse"}
    with pytest.raises(ValueError, match=r"figure8 plays a Box's actions.*Discrete\(6\).*--actions policy"):
        main(["model", str(path), "--env", GAME, "--actions", "figure8", "--out", str(tmp_path / "figure8")])
    with pytest.raises(ValueError, match=r"gives observations of shape \(12, 84, 84\), .* reads \(4, 84, 84\)"):
        main(["model", str(path), "--env", "toy/agent-v0", "--out", str(tmp_path / "toy")])
    assert sorted(path.name for path in tmp_path.iterdir()) == ["analysis"]


def test_callback_logs_during_a2c_ef_training_and_refuses_latent_ef(tmp_path):
    model = A2CEF("CnnPolicy", atari_training_env(), **TINY)
    model.set_logger(configure(str(tmp_path), ["tensorboard"]))
    model.learn(32, callback=ForesightLoggerCallback(atari_env(GAME, 84, 4), log_freq=16, steps=3))
    accumulator = EventAccumulator(str(tmp_path)).Reload()
    assert [event.step for event in accumulator.Images("foresight/prediction")] == [16, 32]
    assert "foresight/prediction_mse" in accumulator.Tags()["scalars"]
    latent = PPOEF("CnnPolicy", atari_training_env(), batch_size=16, **{**TINY, "ef_kwargs": {"target": "latent"}})
    with pytest.raises(ValueError, match="fitted on the model's SequenceReplayBuffer; PPOEF keeps none"):
        ForesightLoggerCallback(atari_env(GAME, 84, 4)).init_callback(latent)
