"""``sb3-ef collect``, ``pretrain`` and ``predict`` end to end on the MuJoCo-free toy world; Meta-World collection."""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from sb3_ef.cli import main
from sb3_ef.ef.babbling import babble
from sb3_ef.envs.toy import ToyAgentEnv
from sb3_ef.offline.collect import collect, record_episode
from sb3_ef.offline.model import load_pretrained
from sb3_ef.offline.predict import LABEL_WIDTH, predict_frames
from sb3_ef.offline.readers import FolderDataset
from tests.helpers.offline import tiny_pretrain


def test_recorded_masks_are_the_env_agent_masks():
    env = ToyAgentEnv(size=32, frame_stack=2, max_episode_steps=6)
    rng = np.random.default_rng(0)
    episode = record_episode(env, lambda _obs: babble(rng, (2,)), seed=3)
    assert episode.frames.shape == (7, 3, 32, 32) and episode.actions.shape == (6, 2)
    assert set(np.unique(episode.actions)) == {-1.0, 1.0}
    replay = ToyAgentEnv(size=32, frame_stack=2, max_episode_steps=6)
    observation, _ = replay.reset(seed=3)
    np.testing.assert_array_equal(observation[-3:], episode.frames[0])
    for t, action in enumerate(episode.actions, start=1):
        observation, *_ = replay.step(action)
        np.testing.assert_array_equal(observation[-3:], episode.frames[t])
        np.testing.assert_array_equal(replay.agent_mask(), episode.masks[t])


def test_collect_pretrain_predict_from_the_command_line(tmp_path, capsys):
    data, run, out = tmp_path / "data", tmp_path / "run", tmp_path / "pred"
    assert main(["collect", "toy/agent-v0", str(data), "--episodes", "3", "--size", "32", "--no-progress"]) == 0
    assert len(FolderDataset(data)) == 3 and FolderDataset(data)[0].masks is not None
    arguments = ["--encoder", "drqv2", "--context", "2", "--horizon", "3", "--steps", "2", "--batch-size", "4"]
    arguments += ["--holdout", "1", "--encoder-kwargs", '{"features_dim": 64}', "--agent-dim", "8", "--no-progress"]
    assert main(["pretrain", str(data), str(run), *arguments]) == 0
    printed = capsys.readouterr().out
    assert '"agent_ratio"' in printed and '"frame_ratio"' in printed
    assert main(["predict", str(run / "model.pt"), str(out), "--dataset", str(data), "--steps", "4"]) == 0
    grid = np.asarray(Image.open(out / "prediction.png"))
    assert grid.shape == (3 * 32 + 2 * 2, LABEL_WIDTH + 4 * 32 + 3 * 2, 3)  # labels, then context / predicted / true
    for row in range(3):  # each row's label is drawn in its band of the label column
        assert grid[row * 34 : row * 34 + 32, :LABEL_WIDTH].max() > 200
    gif = Image.open(out / "prediction.gif")
    assert gif.n_frames == 4 and gif.size == (64, 32)  # predicted | true side by side
    assert (
        main(["predict", str(run / "model.pt"), str(out / "eight"), "--dataset", str(data), "--actions", "figure8"])
        == 0
    )
    eight = Image.open(out / "eight" / "prediction.gif")
    assert eight.size == (32, 32) and eight.n_frames == 3  # horizon frames; no true frames for a hand-made path
    assert json.loads((run / "metrics.json").read_text())["held_out_episodes"] == 1


def test_predictions_go_beyond_the_horizon_and_check_their_input(tmp_path):
    data = tmp_path / "data"
    collect("toy/agent-v0", data, episodes=2, size=32, progress_bar=False)
    tiny_pretrain(data, tmp_path / "run", context=2, steps=1, batch_size=2)
    model, _ = load_pretrained(tmp_path / "run" / "model.pt")
    episode = FolderDataset(data)[0]
    frames = predict_frames(model, episode.frames[:2], np.zeros((9, 2), np.float32))
    assert frames.shape == (9, 32, 32, 3) and frames.dtype == np.uint8
    with pytest.raises(ValueError, match=r"context frames of shape \(2, 3, 32, 32\)"):
        predict_frames(model, episode.frames[:3], np.zeros((4, 2)))
    with pytest.raises(ValueError, match=r"actions of shape \(steps, 2\)"):
        predict_frames(model, episode.frames[:2], np.zeros((4, 3)))


@pytest.mark.slow  # one Meta-World episode: 250 rendered steps, ~15-60 s on 2 busy cores
def test_collect_metaworld_hammer_babbling(tmp_path):
    (path,) = collect("metaworld/hammer", tmp_path, episodes=1, size=64, progress_bar=False)
    episode = FolderDataset(tmp_path)[0]
    assert path.endswith("episode_00000.npz")
    assert episode.frames.shape == (251, 3, 64, 64) and episode.actions.shape == (250, 4)
    assert 0.02 < episode.masks.mean() < 0.5  # the arm fills part of the corner view


def test_labelled_grid_names_each_row():
    from sb3_ef.offline.predict import labelled_grid

    rows = [np.zeros((2, 32, 32, 3), np.uint8)] * 2
    two = labelled_grid(rows, ["context", "prediction"])
    three = labelled_grid([*rows, rows[0]], ["context", "prediction", "truth"])
    assert two.shape == (66, LABEL_WIDTH + 66, 3) and three.shape == (100, LABEL_WIDTH + 66, 3)
    assert not np.array_equal(two[:32, :LABEL_WIDTH], two[34:66, :LABEL_WIDTH])  # different words


@pytest.mark.parametrize("episodes", ["0", "-3", "two"])
def test_collect_refuses_a_non_positive_episode_count(episodes, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["collect", "toy/agent-v0", "unused", "--episodes", episodes])
    assert exit_info.value.code == 2
    assert "argument --episodes: expected a positive integer" in capsys.readouterr().err
    with pytest.raises(ValueError, match="episodes must be a positive number"):
        collect("toy/agent-v0", "unused", episodes=0)


@pytest.mark.parametrize(
    "text, match",
    [
        ("{a: 8}", r"expected a JSON object such as .* \(keys and strings in double quotes\), got '\{a: 8\}'"),
        ("[8]", "expected a JSON object .*, got list"),
    ],
)
def test_pretrain_json_options_explain_what_is_expected(text, match, capsys):
    with pytest.raises(SystemExit):
        main(["pretrain", "unused", "unused", "--ef-kwargs", text])
    assert re.search(f"argument --ef-kwargs: {match}", capsys.readouterr().err)


def test_pretrain_refuses_a_mistyped_ef_option_before_it_reads_the_dataset(tmp_path, capsys):
    ef_kwargs = '{"decoder_chanels": 8}'
    assert main(["pretrain", str(tmp_path / "missing"), str(tmp_path / "out"), "--ef-kwargs", ef_kwargs]) == 2
    error = capsys.readouterr().err
    assert "unknown option decoder_chanels=8 (did you mean 'decoder_channels'" in error and "missing" not in error


def test_pretrain_names_a_file_that_is_not_an_episode_archive_without_suggesting_to_unpickle_it(tmp_path, capsys):
    (tmp_path / "episodes").mkdir()
    (tmp_path / "episodes" / "episode_0.npz").write_bytes(np.random.default_rng(0).bytes(3000))
    assert main(["pretrain", str(tmp_path / "episodes"), str(tmp_path / "out")]) == 2
    error = capsys.readouterr().err
    assert "episode_0.npz (episode 0): not an episode archive (an .npz is a zip of 'frames' and 'actions'" in error
    assert "pickle" not in error


def test_docs_name_the_files_collect_writes(tmp_path):
    (path,) = collect("toy/agent-v0", tmp_path, episodes=1, size=16, progress_bar=False, masks=False)
    docs = (Path(__file__).parents[2] / "docs" / "offline.md").read_text()
    assert os.path.basename(path) == "episode_00000.npz" and "OUT/episode_00000.npz" in docs
    assert "episode_<i>" not in docs


def test_collect_lerobot_round_trip(tmp_path):
    pytest.importorskip("av")
    pytest.importorskip("pyarrow")
    from sb3_ef.offline.lerobot import LeRobotDataset

    env = ToyAgentEnv(size=32, frame_stack=1)
    rng = np.random.default_rng([0, 1])
    reference = record_episode(env, lambda _obs: babble(rng, (2,)), seed=1)  # collect's episode 1
    main(
        [
            "collect",
            "toy/agent-v0",
            str(tmp_path / "ds"),
            "--episodes",
            "2",
            "--size",
            "32",
            "--format",
            "lerobot",
            "--no-progress",
        ]
    )
    dataset = LeRobotDataset(tmp_path / "ds")
    assert len(dataset) == 2 and dataset.camera == "observation.image"
    read = dataset[1]
    np.testing.assert_array_equal(read.actions, reference.actions[: read.steps])
    np.testing.assert_array_equal(read.masks, reference.masks[: len(read.frames)])
    assert np.abs(read.frames.astype(int) - reference.frames[: len(read.frames)]).mean() < 6  # AV1 (lossy)


@pytest.mark.parametrize(
    "option, value, match",
    [("--workers", "-1", "expected an integer >= 0, got -1"), ("--cache-mb", "0", "expected a positive number")],
)
def test_pretrain_streaming_options_are_checked(option, value, match, capsys):
    with pytest.raises(SystemExit):
        main(["pretrain", "unused", "unused", option, value])
    assert f"argument {option}: {match}" in capsys.readouterr().err


def test_predict_names_an_rl_zip_a_truncated_model_and_zero_steps(tmp_path, capsys):
    from stable_baselines3 import PPO

    from sb3_ef.offline.predict import predict_episode

    data, run = tmp_path / "data", tmp_path / "run"
    collect("toy/agent-v0", data, episodes=2, size=32, progress_bar=False, masks=False)
    tiny_pretrain(data, run, context=2, steps=1, batch_size=2)
    PPO("MlpPolicy", "CartPole-v1", n_steps=64, batch_size=32).save(tmp_path / "agent.zip")
    (tmp_path / "cut.pt").write_bytes((run / "model.pt").read_bytes()[:2000])
    for model, message in [
        ("agent.zip", r"agent.zip' is a Stable-Baselines3 model zip .*: pass the OUT/model.pt or OUT/checkpoint.pt"),
        ("cut.pt", r"cut.pt' is not a readable checkpoint of sb3-ef pretrain \(damaged, truncated"),
    ]:
        assert main(["predict", str(tmp_path / model), str(tmp_path / "pred"), "--dataset", str(data)]) == 2
        err = capsys.readouterr().err
        assert re.search(rf"^sb3-ef predict: error: .*{message}", err) and "Traceback" not in err, err
    with pytest.raises(SystemExit):
        main(["predict", str(run / "model.pt"), str(tmp_path / "pred"), "--dataset", str(data), "--steps", "0"])
    assert "argument --steps: expected a positive integer, got 0" in capsys.readouterr().err
    model, _ = load_pretrained(run / "model.pt")
    with pytest.raises(ValueError, match=r"steps must be a positive number of frames to predict \(--steps\), got 0"):
        predict_episode(model, FolderDataset(data)[0], tmp_path / "pred", steps=0)
    assert not (tmp_path / "pred").exists()
