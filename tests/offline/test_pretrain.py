"""Offline pretraining: files written, resuming, the copy baseline, and EF beating it on held-out episodes."""

from __future__ import annotations

import glob
import json

import numpy as np
import pytest
import torch as th

from sb3_ef.offline.evaluate import evaluate, evaluation_picks
from sb3_ef.offline.model import OfflineEF, OfflineEFConfig, load_pretrained
from sb3_ef.offline.pretrain import CHECKPOINT, METRICS, MODEL, pretrain, split_holdout
from tests.helpers.offline import TINY_DRQV2, square_episode

TINY_EF = {"rollout_hidden_dims": (32,), "decoder_channels": 16}


def episodes(count: int = 4, steps: int = 16, size: int = 32) -> list:
    return [square_episode(steps=steps, size=size, seed=seed) for seed in range(count)]


def test_pretrain_writes_model_metrics_tensorboard_and_resumes(tmp_path):
    data = episodes()
    arguments = dict(
        horizon=3, batch_size=4, holdout=1, eval_every=2, ef_kwargs=TINY_EF, progress_bar=False, **TINY_DRQV2
    )
    pretrain(data, tmp_path, steps=2, checkpoint_every=2, **arguments)
    assert th.load(tmp_path / CHECKPOINT, weights_only=False)["step"] == 2
    first, _ = load_pretrained(tmp_path / MODEL)
    model, scores = pretrain(data, tmp_path, steps=4, checkpoint_every=2, **arguments)
    assert th.load(tmp_path / CHECKPOINT, weights_only=False)["step"] == 4
    assert any(
        not th.equal(a, b) for a, b in zip(first.state_dict().values(), model.state_dict().values(), strict=True)
    )
    metrics = json.loads((tmp_path / METRICS).read_text())
    assert metrics["steps"] == 4 and metrics["held_out_episodes"] == 1 and metrics["train_episodes"] == 3
    assert {"frame_ratio", "agent_ratio", "saliency_precision", "saliency_recall"} <= metrics.keys()
    assert len(metrics["agent_mse_per_k"]) == 3 and scores["agent_ratio"] == metrics["agent_ratio"]
    assert glob.glob(str(tmp_path / "tb" / "events.out.tfevents.*"))
    with pytest.raises(ValueError, match="was trained with"):
        pretrain(data, tmp_path, steps=6, **{**arguments, "agent_dim": 16})


def test_copy_baseline_is_the_error_of_repeating_the_last_context_frame():
    data = episodes(count=2, steps=12)
    model = OfflineEF(
        OfflineEFConfig(
            "drqv2",
            (3, 32, 32),
            2,
            context=2,
            horizon=3,
            agent_dim=8,
            encoder_kwargs={"features_dim": 64},
            ef_kwargs=TINY_EF,
        )
    )
    scores = evaluate(model, data, stride=1, saliency_windows=2)
    picks = evaluation_picks(data, 2, 3, stride=1)
    copy_frame, copy_agent = np.zeros(3), np.zeros(3)
    agent_pixels = np.zeros(3)
    for index, t in picks:
        frames, masks = data[index].frames.astype(np.float64) / 255, data[index].masks
        for k in range(1, 4):
            error = ((frames[t] - frames[t + k]) ** 2).mean(axis=0)
            region = masks[t] | masks[t + k]
            copy_frame[k - 1] += error.mean() / len(picks)
            copy_agent[k - 1] += error[region].sum()
            agent_pixels[k - 1] += region.sum()
    np.testing.assert_allclose(scores["copy_frame_mse_per_k"], copy_frame, rtol=1e-5)
    np.testing.assert_allclose(scores["copy_agent_mse_per_k"], copy_agent / agent_pixels, rtol=1e-5)
    assert scores["windows"] == len(picks) == 2 * (12 - 3 - 2 + 2)


def test_holdout_must_leave_training_episodes():
    data = episodes(count=3)
    assert [len(part) for part in split_holdout(data, 0.34)] == [2, 1]
    with pytest.raises(ValueError, match="at least one of 3 episodes"):
        split_holdout(data, 3)


def test_short_episodes_are_refused_before_training(tmp_path):
    from sb3_ef.offline.episodes import write_episode

    write_episode(tmp_path / "data" / "episode_0.npz", square_episode(steps=8))
    with pytest.raises(ValueError, match=r"episode_0.npz \(episode 0\).*shorter than context \+ horizon = 13"):
        pretrain(tmp_path / "data", tmp_path / "run", context=3, horizon=10, steps=1, progress_bar=False)


@pytest.mark.slow  # about 5 minutes on 2 busy cores
def test_ef_beats_copying_the_last_frame_on_held_out_agent_pixels(tmp_path):
    th.set_num_threads(2)
    data = episodes(count=12, steps=30)
    _, scores = pretrain(
        data,
        tmp_path,
        context=2,
        horizon=4,
        steps=300,
        batch_size=16,
        holdout=2,
        learning_rate=2e-3,
        ef_kwargs=TINY_EF,
        progress_bar=False,
        tensorboard=False,
        **TINY_DRQV2,
    )
    assert scores["agent_ratio"] < 0.8, scores
    assert scores["saliency_precision_over_chance"] > 2, scores


def test_corrupt_npz_is_an_episode_error_naming_the_file(tmp_path):
    from sb3_ef.offline.episodes import EpisodeError, write_episode

    for index in range(3):
        write_episode(tmp_path / "data" / f"episode_{index}.npz", square_episode(steps=8, seed=index))
    bad = tmp_path / "data" / "episode_1.npz"
    bad.write_bytes(b"not an npz file at all" * 10)  # numpy alone would try it as a pickle
    with pytest.raises(EpisodeError, match=r"episode_1.npz \(episode 1\): not an episode archive") as error:
        pretrain(tmp_path / "data", tmp_path / "run", context=2, horizon=3, steps=1, progress_bar=False)
    assert "pickle" not in str(error.value)
    bad.write_bytes((tmp_path / "data" / "episode_0.npz").read_bytes()[:-200])  # truncated
    with pytest.raises(EpisodeError, match=r"episode_1.npz \(episode 1\): corrupt or truncated"):
        pretrain(tmp_path / "data", tmp_path / "run", context=2, horizon=3, steps=1, progress_bar=False)


def test_a_finished_run_is_kept_unless_overwrite(tmp_path):
    data = episodes(count=3, steps=10)
    arguments = {
        "horizon": 3,
        "batch_size": 4,
        "holdout": 1,
        "ef_kwargs": TINY_EF,
        "progress_bar": False,
        "tensorboard": False,
    }
    pretrain(data, tmp_path, steps=2, **arguments, **TINY_DRQV2)
    written = (tmp_path / MODEL).stat().st_mtime_ns, (tmp_path / METRICS).read_text()
    with pytest.raises(FileExistsError, match=r"model.pt holds a finished run of 2 steps: pass overwrite=True"):
        pretrain(data, tmp_path, steps=2, **arguments, **TINY_DRQV2)
    with pytest.raises(FileExistsError, match="finished run of 2 steps"):
        pretrain(data, tmp_path, steps=2, resume=False, **arguments, **TINY_DRQV2)
    assert ((tmp_path / MODEL).stat().st_mtime_ns, (tmp_path / METRICS).read_text()) == written
    pretrain(data, tmp_path, steps=2, overwrite=True, resume=False, **arguments, **TINY_DRQV2)
    assert (tmp_path / MODEL).stat().st_mtime_ns != written[0]


def test_held_out_evaluation_shows_progress(tmp_path, capsys):
    data = episodes(count=3, steps=10)
    pretrain(
        data,
        tmp_path,
        horizon=3,
        steps=1,
        batch_size=2,
        holdout=1,
        saliency_windows=2,
        ef_kwargs=TINY_EF,
        tensorboard=False,
        **TINY_DRQV2,
    )
    err = capsys.readouterr().err
    assert "pretrain" in err and "held-out evaluation" in err and "3/3" in err  # 1 prediction batch + 2 saliency


@pytest.mark.parametrize("encoder", ["dcgan-unet", "drqv2", "tdmpc2"])
def test_a_mistyped_encoder_kwarg_is_one_line_naming_it(encoder, tmp_path, capsys):
    from sb3_ef.cli import main
    from sb3_ef.offline.episodes import write_episode

    for seed in range(2):
        write_episode(tmp_path / "data" / f"episode_{seed}.npz", square_episode(steps=16, size=64, seed=seed))
    argv = ["pretrain", str(tmp_path / "data"), str(tmp_path / "run"), "--encoder", encoder, "--steps", "1"]
    assert main([*argv, "--encoder-kwargs", '{"widht": 64, "in_channels": 3}', "--no-progress"]) == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and "unknown key 'widht'" in error and f"the {encoder} encoder's" in error
    assert ("did you mean 'width'?" in error) == (encoder == "dcgan-unet")
    set_by_pretrain = {"dcgan-unet": "in_channels", "drqv2": "observation_space", "tdmpc2": "action_dim"}[encoder]
    assert set_by_pretrain not in error.split("expected one of")[1]
