import csv

import gymnasium as gym
import pytest
from stable_baselines3 import A2C
from stable_baselines3.common.callbacks import EvalCallback
from stable_baselines3.common.env_util import make_vec_env

from sb3_ef.analysis.records import RECORD_COLUMNS, EvalRecorderCallback, append_records


class SuccessOnTimeLimit(gym.Wrapper):
    """Reports is_success like Meta-World does: here, true when the episode reached its time limit."""

    def step(self, action):
        observation, reward, terminated, truncated, info = self.env.step(action)
        info["is_success"] = truncated
        return observation, reward, terminated, truncated, info


def short_cartpole_with_success():
    return SuccessOnTimeLimit(gym.make("CartPole-v1", max_episode_steps=5))


def _read(path):
    with open(path, newline="") as file:
        return list(csv.DictReader(file))


def _train_with_recorder(path, eval_env_id="CartPole-v1", seed=3):
    model = A2C("MlpPolicy", "CartPole-v1", n_steps=4, seed=seed, device="cpu")
    eval_env = make_vec_env(eval_env_id, n_envs=1, seed=0)
    recorder = EvalRecorderCallback(path, action_repeat=2)
    model.learn(16, callback=EvalCallback(eval_env, eval_freq=8, n_eval_episodes=2, callback_after_eval=recorder))
    return model


def test_recorder_writes_one_row_per_evaluation_and_appends(tmp_path):
    path = tmp_path / "runs" / "cartpole.csv"
    _train_with_recorder(path)
    with open(path) as file:
        assert file.readline().strip() == ",".join(RECORD_COLUMNS)
    rows = _read(path)
    assert [int(row["step"]) for row in rows] == [8, 16]
    assert [int(row["frame"]) for row in rows] == [16, 32]
    assert {row["algo"] for row in rows} == {"A2C"} and {row["task"] for row in rows} == {"CartPole-v1"}
    assert {row["seed"] for row in rows} == {"3"} and {row["success"] for row in rows} == {""}
    assert all(float(row["return"]) >= 1 for row in rows)
    _train_with_recorder(path, seed=4)  # a second run appends below, header once
    rows = _read(path)
    assert [row["seed"] for row in rows] == ["3", "3", "4", "4"]
    with open(path) as file:
        assert sum(line.startswith("algo,") for line in file) == 1


def test_success_rate_is_recorded_when_the_env_reports_it(tmp_path):
    path = tmp_path / "success.csv"
    _train_with_recorder(path, eval_env_id=short_cartpole_with_success)
    rows = _read(path)
    assert [float(row["success"]) for row in rows] == [1.0, 1.0]
    assert all(float(row["return"]) == 5.0 for row in rows)


def test_foreign_csv_is_never_overwritten(tmp_path):
    path = tmp_path / "mine.csv"
    path.write_text("x,y\n1,2\n")
    row = dict.fromkeys(RECORD_COLUMNS, 0)
    with pytest.raises(ValueError, match="refusing to append"):
        append_records(path, [row])
    assert path.read_text() == "x,y\n1,2\n"
    with pytest.raises(ValueError, match="Expected record columns"):
        append_records(tmp_path / "new.csv", [{"algo": "a"}])


def test_recorder_outside_eval_callback_is_refused(tmp_path):
    model = A2C("MlpPolicy", "CartPole-v1", n_steps=4, device="cpu")
    with pytest.raises(TypeError, match="callback_after_eval"):
        model.learn(4, callback=EvalRecorderCallback(tmp_path / "x.csv"))
