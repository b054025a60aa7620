"""rl-zoo3 training runs from the zoo configs, enjoy without a full replay buffer, and bad command lines."""

from __future__ import annotations

from pathlib import Path

import pytest
from rl_zoo3 import utils

from sb3_ef.analysis.metrics import load_records
from sb3_ef.zoo import enjoy, train
from sb3_ef.zoo.config import ZOO_ALGORITHMS
from sb3_ef.zoo.records import export_records
from sb3_ef.zoo.registration import algorithm_classes
from tests.helpers.zoo import ENV_KWARGS, HYPERPARAMS, train_args

ENV_ID = "dmc/cartpole-swingup-v0"
LOG_NAME = "dmc-cartpole-swingup-v0"  # rl-zoo3 writes "/" in env ids as "-" in folder names
STEPS = 200


def saved_model(log_folder: Path, algo: str, run: int = 1) -> Path:
    return log_folder / algo / f"{LOG_NAME}_{run}" / f"{LOG_NAME}.zip"


@pytest.fixture(scope="module")
def trained(tmp_path_factory) -> Path:
    """One short run per algorithm key, from its YAML file (the 'default' entry) with small-size overrides;
    the drqv2 run is evaluated every 60 steps."""
    log_folder = tmp_path_factory.mktemp("logs")
    for algo in ZOO_ALGORITHMS:
        evaluation = ["--eval-freq", "60", "--eval-episodes", "1"] if algo == "drqv2" else []
        train.main([*train_args(algo, ENV_ID, str(log_folder), n_timesteps=STEPS), *evaluation])
    return log_folder


@pytest.mark.parametrize("algo", ZOO_ALGORITHMS)
def test_training_runs_and_saves_a_loadable_model(trained, algo):
    path = saved_model(trained, algo)
    assert path.is_file()
    model = algorithm_classes()[algo].load(path, device="cpu")
    assert model.num_timesteps == STEPS
    assert model.batch_size == HYPERPARAMS[algo]["batch_size"] if algo != "a2c_ef" else model.n_steps == 20
    assert model.observation_space.shape == (9, ENV_KWARGS[algo]["size"], ENV_KWARGS[algo]["size"])
    # Updates happened after the warm-up (learning_starts 40).
    assert model._n_updates > 0
    params = (trained / algo / f"{LOG_NAME}_1" / LOG_NAME / "args.yml").read_text()
    assert "sb3_ef" in params  # recorded among --gym-packages


def test_enjoy_loads_without_the_training_buffer(trained, capsys, monkeypatch):
    """rl-zoo3 enjoy with our loader: the replay buffer is rebuilt small, not at the trained capacity."""
    sizes = {}
    original = enjoy.InferenceLoader.load

    def recording_load(self, path, **kwargs):
        model = original(self, path, **kwargs)
        sizes["buffer"] = model.replay_buffer.buffer_size
        sizes["bytes"] = model.replay_buffer.nbytes
        return model

    monkeypatch.setattr(enjoy.InferenceLoader, "load", recording_load)
    enjoy.main(["--algo", "drqv2_ef", "--env", ENV_ID, "-f", str(trained), "--no-render", "-n", "25"])
    assert "Episode Reward" in capsys.readouterr().out
    assert sizes["buffer"] == enjoy.INFERENCE_BUFFER_SIZE
    # A plain load rebuilds the buffer at its trained capacity.
    plain = algorithm_classes()["drqv2_ef"].load(saved_model(trained, "drqv2_ef"), device="cpu")
    assert plain.replay_buffer.buffer_size == HYPERPARAMS["drqv2_ef"]["buffer_size"]
    assert sizes["bytes"] * 4 < plain.replay_buffer.nbytes
    # The loader is only in place during enjoy.
    assert utils.ALGOS["drqv2_ef"] is algorithm_classes()["drqv2_ef"]


def test_evaluations_of_a_zoo_run_export_to_analysis_records(trained, tmp_path):
    [path] = export_records(str(trained), str(tmp_path))
    records = load_records(tmp_path)
    assert path.endswith(f"DrQv2/{LOG_NAME}_1.csv")  # the class name, as EvalRecorderCallback writes it
    assert records["step"].tolist() == [60, 120, 180]
    assert records["frame"].tolist() == [120, 240, 360]
    assert set(records["task"]) == {ENV_ID} and set(records["seed"]) == {0}


def test_unknown_algorithm_is_named(tmp_path):
    with pytest.raises(ValueError, match=r"Unknown algorithm 'drqv3_ef'.*drqv2_ef"):
        train.main(["--algo", "drqv3_ef", "--env", ENV_ID, "-f", str(tmp_path)])


def test_unknown_env_id_is_named(tmp_path):
    with pytest.raises(ValueError, match=r"Unknown env id 'dmc/cartpole-swingdown-v0'"):
        train.main(["--algo", "drqv2_ef", "--env", "dmc/cartpole-swingdown-v0", "-f", str(tmp_path)])


def test_unknown_yaml_key_is_named_before_anything_is_built(tmp_path):
    conf = tmp_path / "bad.yml"
    conf.write_text("default:\n  policy: CnnPolicy\n  n_timesteps: 100\n  bufer_size: 10\n")
    with pytest.raises(ValueError, match=r"bad.yml, entry 'default': unknown key 'bufer_size'"):
        train.main(["--algo", "drqv2", "--env", ENV_ID, "-f", str(tmp_path), "--conf-file", str(conf)])
    assert not (tmp_path / "drqv2").exists()


def test_unknown_override_key_is_named(tmp_path):
    with pytest.raises(ValueError, match=r"--hyperparams: unknown key 'bta'"):
        train.main(["--algo", "drqv2_ef", "--env", ENV_ID, "-f", str(tmp_path), "--hyperparams", "bta:2.0"])


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        ([], ["--gym-packages", "sb3_ef"]),
        (["--gym-packages", "my_envs"], ["--gym-packages", "sb3_ef", "my_envs"]),
        (["--gym-packages=my_envs"], ["--gym-packages=my_envs"]),
    ],
)
def test_sb3_ef_is_added_to_gym_packages(argv, expected):
    assert train.with_gym_package(argv) == expected
