"""DreamerV3 (sheeprl's Dreamer-v3 behind SB3's interface): training with evaluation records, continuing, predict
with the recurrent state, save / load, and the inputs refused before training."""

from __future__ import annotations

import csv
import zipfile
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from stable_baselines3.common.vec_env import DummyVecEnv

from sb3_ef.analysis.records import RECORD_COLUMNS
from sb3_ef.zoo.config import default_config_path, load_config

pytest.importorskip("sheeprl")

from sb3_ef.dreamerv3 import DreamerV3, Evaluation

#: The CPU-sized entry of zoo_configs/dreamerv3.yml, with a shorter warm-up and smaller batches.
ENTRY = load_config(default_config_path("dreamerv3"))["toy/agent-v0"]
ENV_KWARGS = ENTRY["env_kwargs"]
SMALL = {"buffer_size": 2000, "learning_starts": 16, "batch_size": 4, "sequence_length": 8}
KWARGS = {key: value for key, value in ENTRY.items() if key not in ("policy", "n_timesteps", "env_kwargs")} | SMALL


def toy(frame_stack: int | None = None) -> gym.Env:
    kwargs = ENV_KWARGS if frame_stack is None else {**ENV_KWARGS, "frame_stack": frame_stack}
    return gym.make("toy/agent-v0", **kwargs)


def model(work_dir: Path, seed: int = 0, **kwargs) -> DreamerV3:
    return DreamerV3("CnnPolicy", toy(), **{**KWARGS, **kwargs}, work_dir=work_dir, seed=seed, device="cpu")


def evaluation(path: Path, freq: int = 20) -> Evaluation:
    return Evaluation(toy(), freq, 2, path, algo="DreamerV3", task="toy/agent-v0", seed=0, action_repeat=1)


@pytest.fixture(scope="module")
def trained(tmp_path_factory) -> tuple[DreamerV3, Path]:
    """40 steps (training from step 16), evaluated every 20 steps, one checkpoint at the end."""
    folder = tmp_path_factory.mktemp("dreamerv3")
    trained = model(folder / "run").learn(40, evaluation=evaluation(folder / "records.csv"))
    return trained, folder


def test_learn_trains_and_records_each_evaluation_in_the_csv_format(trained):
    model, folder = trained
    assert model.num_timesteps == 40
    with open(folder / "records.csv", newline="") as file:
        rows = list(csv.DictReader(file))
    assert tuple(rows[0]) == RECORD_COLUMNS
    assert [(row["algo"], row["task"], row["seed"], row["step"], row["frame"]) for row in rows] == [
        ("DreamerV3", "toy/agent-v0", "0", "20", "20"),
        ("DreamerV3", "toy/agent-v0", "0", "40", "40"),
    ]
    assert all(-50 < float(row["return"]) < 0 and row["success"] == "" for row in rows)  # 25 steps of -distance
    state = th.load(model._checkpoint, weights_only=False)
    assert state["per_rank_gradient_steps"] > 0 and state["iter_num"] == 40  # sheeprl trained, checkpointed at 40


def test_predict_carries_the_recurrent_state_and_resets_at_episode_starts(trained):
    model, _ = trained
    env = toy(frame_stack=3)  # any stack: the newest frame is read
    observation, _ = env.reset(seed=5)
    action, state = model.predict(observation, deterministic=True)
    assert action.shape == (2,) and env.action_space.contains(action)
    assert [array.shape for array in state] == [(1, 1, 64), (1, 1, 64), (1, 1, 2)]
    observation, *_ = env.step(action)
    _, next_state = model.predict(observation, state=state, deterministic=True)
    assert not np.array_equal(next_state[0], state[0])  # the memory moved on
    batch = np.stack([observation, observation])
    actions, batch_state = model.predict(batch, episode_start=np.array([True, False]))
    assert actions.shape == (2, 2) and batch_state[0].shape == (1, 2, 64)
    with pytest.raises(ValueError, match="state must be the 3 arrays"):
        model.predict(observation, state=batch_state)
    with pytest.raises(ValueError, match="stacked uint8 RGB frames"):
        model.predict(observation.astype(np.float32))


def test_a_saved_model_loads_and_acts_as_the_trained_one(trained, tmp_path):
    model, _ = trained
    model.save(tmp_path / "model.zip")
    loaded = DreamerV3.load(tmp_path / "model.zip", device="cpu", work_dir=tmp_path / "loaded")
    assert loaded.num_timesteps == 40 and loaded.settings == model.settings and loaded.env is None
    observation, _ = toy().reset(seed=7)
    actions = [agent.predict(observation, deterministic=True)[0] for agent in (model, loaded)]
    np.testing.assert_array_equal(actions[0], actions[1])


def test_a_loaded_model_goes_on_training_with_a_new_replay_buffer(trained, tmp_path):
    model, _ = trained
    model.save(tmp_path / "model.zip")
    loaded = DreamerV3.load(tmp_path / "model.zip", env=toy(), device="cpu", work_dir=tmp_path / "loaded")
    loaded.learn(20, reset_num_timesteps=False, evaluation=evaluation(tmp_path / "records.csv"))
    assert loaded.num_timesteps == 60
    with open(tmp_path / "records.csv", newline="") as file:
        assert [row["step"] for row in csv.DictReader(file)] == ["60"]


def test_bf16_trains_in_fabrics_bf16_mixed_and_load_keeps_it(tmp_path):
    bf16 = model(tmp_path / "run", precision="bf16").learn(20)
    assert bf16.resolved.fabric.precision == "bf16-mixed"
    bf16.save(tmp_path / "model.zip")
    loaded = DreamerV3.load(tmp_path / "model.zip", device="cpu", work_dir=tmp_path / "loaded")
    assert loaded.settings["precision"] == "bf16" and loaded.cfg.fabric.precision == "bf16-mixed"


def test_a_trained_model_continues_its_step_count_only(trained):
    model, _ = trained
    with pytest.raises(ValueError, match="has trained 40 steps: continue with learn"):
        model.learn(10)


def test_files_that_are_not_dreamerv3_models_are_refused(trained, tmp_path):
    model, _ = trained
    with zipfile.ZipFile(tmp_path / "other.zip", "w") as archive:
        archive.writestr("data", "{}")
    with pytest.raises(ValueError, match="is not a DreamerV3 model: expected the files"):
        DreamerV3.load(tmp_path / "other.zip")
    model.save(tmp_path / "model.zip")
    content = (tmp_path / "model.zip").read_bytes()
    (tmp_path / "cut.zip").write_bytes(content[: len(content) // 2])
    with pytest.raises(ValueError, match="not a complete zip archive"):
        DreamerV3.load(tmp_path / "cut.zip")
    with pytest.raises(FileNotFoundError, match="No saved DreamerV3 model"):
        DreamerV3.load(tmp_path / "missing.zip")


def test_training_leaves_the_process_wide_torch_settings_as_they_were(tmp_path):
    before = (
        th.get_float32_matmul_precision(),
        th.backends.cudnn.benchmark,
        th.distributions.Distribution._validate_args,
    )
    th.backends.cudnn.benchmark = False  # sheeprl's configuration turns it on
    model(tmp_path).learn(20)
    assert (th.get_float32_matmul_precision(), th.backends.cudnn.benchmark) == (before[0], False)
    assert th.distributions.Distribution._validate_args == before[2]
    th.backends.cudnn.benchmark = before[1]


def test_evaluations_leave_the_training_as_it_is_without_them(tmp_path):
    """Evaluating draws its own random numbers: the weights after training are those of a run without
    evaluations. Evaluations and checkpoints keep their own steps."""
    with_evaluation = model(tmp_path / "a").learn(
        30, evaluation=evaluation(tmp_path / "a.csv", freq=10), checkpoint_freq=15, keep_checkpoints=None
    )
    without = model(tmp_path / "b").learn(30)
    with open(tmp_path / "a.csv", newline="") as file:
        assert [row["step"] for row in csv.DictReader(file)] == ["10", "20", "30"]
    assert sorted(path.name for path in (tmp_path / "a").rglob("ckpt_*.ckpt")) == ["ckpt_15_0.ckpt", "ckpt_30_0.ckpt"]
    for name in ("world_model", "actor", "critic"):
        for key, value in with_evaluation._weights()[name].items():
            th.testing.assert_close(value, without._weights()[name][key], rtol=0, atol=0, msg=f"{name}.{key}")


@pytest.mark.parametrize(
    ("build", "message"),
    [
        (lambda tmp: DreamerV3("MlpPolicy", toy(), work_dir=tmp), "policy is 'CnnPolicy'"),
        (lambda tmp: DreamerV3("CnnPolicy", DummyVecEnv([toy, toy]), work_dir=tmp), "got a DummyVecEnv of 2 envs"),
        (
            lambda tmp: DreamerV3("CnnPolicy", toy(), sheeprl_overrides={"algo.horizonn": 5}, work_dir=tmp),
            "'algo.horizonn' is not a key of sheeprl",
        ),
        (lambda tmp: DreamerV3("CnnPolicy", toy(), device="tpu", work_dir=tmp), "device must be"),
        (lambda tmp: DreamerV3("CnnPolicy", toy(), precision="fp16", work_dir=tmp), "Unknown precision 'fp16'"),
        (
            lambda tmp: DreamerV3("CnnPolicy", toy(), sheeprl_overrides={"fabric.precision": "16-mixed"}, work_dir=tmp),
            "'fabric.precision' is set by DreamerV3 from precision",
        ),
        (lambda tmp: model(tmp).learn(10, callback=5), "callback must be an SB3 BaseCallback, a function"),
        (lambda tmp: model(tmp).learn(0), "total_timesteps must be a positive integer"),
        (lambda tmp: model(tmp).learn(10, checkpoint_freq=0), "checkpoint_freq must be a positive integer, got 0"),
        (lambda tmp: DreamerV3.load(tmp / "nothing.zip"), "No saved DreamerV3 model"),
    ],
)
def test_bad_input_is_refused_before_training(build, message, tmp_path):
    with pytest.raises((ValueError, FileNotFoundError), match=message):
        build(tmp_path)
