"""SB3's contract on DreamerV3: deterministic and vectorised predict, save / load round trips (paths with or without
``.zip``, file objects), callbacks, learning twice, the device fallback, the checks of sheeprl_overrides and of frame
sizes, and loads across classes naming the class in the file."""

from __future__ import annotations

import io
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from stable_baselines3.common.callbacks import BaseCallback

from sb3_ef.zoo.config import default_config_path, load_config

pytest.importorskip("sheeprl")

from sb3_ef.dreamerv3 import DreamerV3
from sb3_ef.drqv2 import DrQv2EF

#: The CPU-sized entry of zoo_configs/dreamerv3.yml, with a shorter warm-up and the smallest batches.
ENTRY = load_config(default_config_path("dreamerv3"))["toy/agent-v0"]
TINY = {key: value for key, value in ENTRY.items() if key not in ("policy", "n_timesteps", "env_kwargs")} | {
    "buffer_size": 500,
    "learning_starts": 8,
    "batch_size": 2,
    "sequence_length": 4,
}


def toy(size: int = 16) -> gym.Env:
    return gym.make("toy/agent-v0", **{**ENTRY["env_kwargs"], "size": size})


def tiny(work_dir: Path, **kwargs) -> DreamerV3:
    return DreamerV3("CnnPolicy", toy(), **{**TINY, **kwargs}, work_dir=work_dir, seed=0, device="cpu")


class Recorder(BaseCallback):
    """Records SB3's calls: the step count at each ``on_step``; returns ``False`` at ``stop_at`` calls."""

    def __init__(self, stop_at: int | None = None):
        super().__init__()
        self.stop_at = stop_at
        self.steps: list[int] = []
        self.events: list[str] = []

    def _on_training_start(self) -> None:
        self.events.append(f"start at {self.num_timesteps} of {self.locals['total_timesteps']}")

    def _on_step(self) -> bool:
        self.steps.append(self.num_timesteps)
        return self.stop_at is None or self.n_calls < self.stop_at

    def _on_training_end(self) -> None:
        self.events.append("end")


@pytest.fixture(scope="module")
def trained(tmp_path_factory) -> tuple[DreamerV3, Recorder]:
    """12 steps (training from step 8) with a callback, then 4 more with the same callback."""
    recorder = Recorder()
    model = tiny(tmp_path_factory.mktemp("dreamerv3")).learn(12, callback=recorder)
    model.learn(4, callback=recorder, reset_num_timesteps=False)
    return model, recorder


def test_callbacks_see_every_env_step_and_learn_continues_its_count(trained):
    model, recorder = trained
    assert recorder.steps == list(range(1, 17))
    assert recorder.events == ["start at 0 of 12", "end", "start at 12 of 16", "end"]
    assert model.num_timesteps == 16


def test_deterministic_predict_is_the_same_for_the_same_observation(trained):
    model, _ = trained
    observation, _ = toy().reset(seed=3)
    actions = np.stack([model.predict(observation, deterministic=True)[0] for _ in range(5)])
    np.testing.assert_array_equal(actions, np.repeat(actions[:1], 5, axis=0))
    sampled = np.stack([model.predict(observation)[0] for _ in range(5)])
    assert np.ptp(sampled, axis=0).max() > 0  # without deterministic, actions are drawn


def test_vectorised_predict_acts_on_each_observation_as_alone(trained):
    model, _ = trained
    observations = np.stack([toy().reset(seed=seed)[0] for seed in range(3)])
    actions, state = model.predict(observations, deterministic=True)
    assert actions.shape == (3, 2) and state[0].shape[1] == 3
    alone = np.stack([model.predict(observation, deterministic=True)[0] for observation in observations])
    np.testing.assert_allclose(actions, alone, rtol=0, atol=1e-6)


@pytest.mark.parametrize("name", ["model", "model.zip"])
def test_save_adds_zip_and_load_takes_the_path_either_way(trained, tmp_path, name):
    model, _ = trained
    model.save(tmp_path / name)
    assert sorted(path.name for path in tmp_path.iterdir()) == ["model.zip"]
    observation, _ = toy().reset(seed=4)
    expected, _ = model.predict(observation, deterministic=True)
    for given in ("model", "model.zip"):
        loaded = DreamerV3.load(tmp_path / given, device="cpu", work_dir=tmp_path / "work")
        assert loaded.num_timesteps == 16
        np.testing.assert_array_equal(loaded.predict(observation, deterministic=True)[0], expected)


def test_save_and_load_take_file_objects(trained, tmp_path):
    model, _ = trained
    file = io.BytesIO()
    model.save(file)
    file.seek(0)
    loaded = DreamerV3.load(file, device="cpu", work_dir=tmp_path)
    for name in ("world_model", "actor", "critic"):
        for key, value in model._weights()[name].items():
            th.testing.assert_close(loaded._weights()[name][key], value, rtol=0, atol=0)


def test_a_callback_returning_false_stops_the_run(tmp_path):
    recorder = Recorder(stop_at=10)
    model = tiny(tmp_path).learn(16, callback=recorder, checkpoint_freq=4)
    assert recorder.steps == list(range(1, 11)) and recorder.events[-1] == "end"
    assert model.num_timesteps == 8  # the weights of the newest checkpoint step before the stop


def test_frames_of_another_size_than_the_trained_one_are_named(trained, tmp_path):
    model, _ = trained
    with pytest.raises(ValueError, match="trained on 16x16 frames, the observation gives 32x32"):
        model.predict(toy(size=32).reset(seed=0)[0])
    model.save(tmp_path / "model.zip")
    with pytest.raises(ValueError, match="trained on 16x16 frames, the env gives 32x32"):
        DreamerV3.load(tmp_path / "model.zip", env=toy(size=32), device="cpu", work_dir=tmp_path / "work")


def test_other_classes_name_the_class_in_the_file(trained, tmp_path):
    model, _ = trained
    model.save(tmp_path / "dreamer.zip")
    with pytest.raises(ValueError, match=r"saved by DreamerV3, use DreamerV3\.load"):
        DrQv2EF.load(tmp_path / "dreamer.zip")
    DrQv2EF("CnnPolicy", toy(size=32), buffer_size=100).save(tmp_path / "drqv2.zip")
    with pytest.raises(ValueError, match=r"saved by DrQv2EF, use DrQv2EF\.load"):
        DreamerV3.load(tmp_path / "drqv2.zip")


@pytest.mark.skipif(th.cuda.is_available(), reason="the fallback is for machines without CUDA")
def test_cuda_without_a_gpu_falls_back_to_the_cpu_with_a_warning(tmp_path):
    with pytest.warns(UserWarning, match="CUDA"):
        model = DreamerV3("CnnPolicy", toy(), **TINY, work_dir=tmp_path, device="cuda")
    assert model.device == "cpu"


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ("algo.horizon=5", r"must be a dict of dotted sheeprl keys .* got 'algo.horizon=5' \(str\)"),
        ({"algo.horizn": 5}, r"'algo.horizn' is not a key .*did you mean 'algo.horizon'"),
        ({"algo.horizon": 2.5}, r"'algo.horizon' must be a whole number \(sheeprl's default is 15\), got 2.5"),
        ({"algo.actor.optimizer.lr": "1e-4"}, r"'algo.actor.optimizer.lr' must be a number .* got '1e-4' \(str\)"),
        ({"fabric.precision": 16}, r"'fabric.precision' must be a string"),
    ],
)
def test_sheeprl_overrides_are_checked_at_construction(overrides, message, tmp_path):
    with pytest.raises(ValueError, match=message):
        DreamerV3("CnnPolicy", toy(), sheeprl_overrides=overrides, work_dir=tmp_path)
