"""``sb3-ef benchmark --dry-run`` checks what each row's start checks (its env and data, its algorithm's arguments,
CURL's crop, Dreamer-v3's sheeprl overrides and frames, Distracting Control's options and background videos), names
every bad row with the argument, the value and what is expected, and exits with status 2; nothing trains."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import yaml

from sb3_ef import cli
from sb3_ef.envs.distracting.davis import DAVIS_TRAIN_VIDEOS

HERE = Path(__file__).parent
#: A row small enough to build at once (its model is never built: only its class's arguments are checked).
SMALL = {"buffer_size": 1000, "batch_size": 8, "learning_starts": 10}
TASK = "dmc/cartpole-balance-v0"


def block(algorithms: Any, tasks: list[str], env_kwargs: dict[str, Any] | None = None) -> dict[str, Any]:
    return {
        "algorithms": algorithms,
        "tasks": tasks,
        "seeds": 2,
        "n_timesteps": 200,
        "eval_freq": 100,
        "env_kwargs": {"fast_render": True, **(env_kwargs or {})},
    }


def benchmark(tmp_path: Path, capsys, *blocks: dict[str, Any], dry_run: bool = True) -> tuple[int, list[str]]:
    """``sb3-ef benchmark`` on a grid of ``blocks``: its exit status and the lines it wrote to stderr."""
    grid = tmp_path / "grid.yml"
    grid.write_text(yaml.safe_dump({"grids": list(blocks)}))
    argv = ["benchmark", str(grid), "--out", str(tmp_path / "out"), *(["--dry-run"] if dry_run else [])]
    status = cli.main(argv)
    return status, capsys.readouterr().err.splitlines()


@pytest.fixture(autouse=True)
def _no_traceback(monkeypatch):
    monkeypatch.delenv("SB3_EF_TRACEBACK", raising=False)
    monkeypatch.delenv("SB3_EF_DAVIS_DIR", raising=False)


def test_a_grid_whose_rows_can_start_passes(tmp_path, capsys):
    status, errors = benchmark(tmp_path, capsys, *yaml.safe_load((HERE / "tiny_grid.yml").read_text())["grids"])
    assert (status, errors) == (0, [])
    assert not (tmp_path / "out").exists()  # nothing written


def test_an_unknown_env_option_is_named_with_the_row(tmp_path, capsys):
    status, errors = benchmark(tmp_path, capsys, block({"drqv2": {"hyperparams": SMALL}}, [TASK], {"frame_stak": 2}))
    assert status == 2
    assert errors[0] == "sb3-ef benchmark: error: 1 problem in the grid, nothing trained:"
    assert errors[1].startswith(
        f"  drqv2 on {TASK}: Unknown env option 'frame_stak' for {TASK} (did you mean 'frame_stack'?); expected one of"
    )


def test_an_argument_value_is_checked_as_construction_checks_it(tmp_path, capsys):
    algorithms = {"curl": {"hyperparams": {**SMALL, "ent_coef": "bogus"}}}
    status, errors = benchmark(tmp_path, capsys, block(algorithms, [TASK], {"size": 100}))
    assert status == 2
    assert errors[1] == (
        f"  curl on {TASK}: CURL: ent_coef must be a number >= 0 (a fixed entropy coefficient), 'auto' or "
        "'auto_<initial value > 0>' (learned), got str 'bogus'"
    )


def test_curl_at_64_pixels_is_refused_for_its_84_pixel_crop(tmp_path, capsys):
    status, errors = benchmark(tmp_path, capsys, block({"curl": {"hyperparams": SMALL}}, [TASK], {"size": 64}))
    assert status == 2
    assert errors[1] == (
        f"  curl on {TASK}: CURL's crop_size must be an int in [1, 64] (at most the 64x64 frames: render larger "
        "frames, e.g. make_env(..., size=100) for crops of 84), got 84"
    )


def test_td3_ef_rows_build_rl_zoo3s_action_noise_from_the_config(tmp_path, capsys):
    # zoo_configs/td3_ef.yml explores with noise_type / noise_std, which rl-zoo3 turns into action_noise.
    status, errors = benchmark(tmp_path, capsys, block({"td3_ef": {"hyperparams": SMALL}}, [TASK]))
    assert (status, errors) == (0, [])
    status, errors = benchmark(
        tmp_path, capsys, block({"td3_ef": {"hyperparams": {**SMALL, "noise_type": "gaussian"}}}, [TASK])
    )
    assert status == 2
    assert errors[1] == f"  td3_ef on {TASK}: noise_type must be one of 'normal', 'ornstein-uhlenbeck', got 'gaussian'"


def test_a_misspelt_sheeprl_override_is_named_with_the_close_key(tmp_path, capsys):
    pytest.importorskip("sheeprl")
    algorithms = {"dreamerv3": {"hyperparams": {"sheeprl_overrides": {"algo.horizn": 15}}}}
    status, errors = benchmark(tmp_path, capsys, block(algorithms, ["toy/agent-v0"]) | {"env_kwargs": {}})
    assert status == 2
    assert errors[1].startswith(
        "  dreamerv3 on toy/agent-v0: sheeprl_overrides: 'algo.horizn' is not a key of sheeprl's Dreamer-v3 "
        "configuration (did you mean 'algo.horizon'"
    )


def test_a_dreamerv3_row_on_an_env_without_frames_is_refused(tmp_path, capsys):
    pytest.importorskip("sheeprl")
    conf = tmp_path / "dreamerv3.yml"
    conf.write_text(yaml.safe_dump({"default": {"policy": "CnnPolicy", "n_timesteps": 200, "model_size": "XS"}}))
    algorithms = {"dreamerv3": {"conf_file": str(conf)}}
    status, errors = benchmark(tmp_path, capsys, block(algorithms, ["Pendulum-v1"]) | {"env_kwargs": {}})
    assert status == 2
    assert errors[1].startswith(
        "  dreamerv3 on Pendulum-v1: DreamerV3 expects stacked RGB frames: a uint8 Box of shape (3 * frame_stack, "
        "height, width), got Box("
    )


DISTRACTING = "dmc-distracting/cartpole-balance-v0"


def test_a_misspelt_distracting_difficulty_is_named(tmp_path, capsys):
    env_kwargs = {"distraction": "color", "difficulty": "medum"}
    status, errors = benchmark(tmp_path, capsys, block({"drqv2": {"hyperparams": SMALL}}, [DISTRACTING], env_kwargs))
    assert status == 2
    assert errors[1] == (
        f"  drqv2 on {DISTRACTING}: Unknown difficulty 'medum' (did you mean 'medium'?); expected one of 'easy', "
        "'medium', 'hard'"
    )


@pytest.mark.parametrize("folder", ["missing", "empty"])
def test_a_missing_or_empty_background_folder_is_named(tmp_path, capsys, folder):
    (tmp_path / "empty").mkdir()
    env_kwargs = {"distraction": "background", "background_dir": str(tmp_path / folder)}
    status, errors = benchmark(tmp_path, capsys, block({"drqv2": {"hyperparams": SMALL}}, [DISTRACTING], env_kwargs))
    assert status == 2
    expected = "is not a folder" if folder == "missing" else "holds no DAVIS videos"
    assert errors[1].startswith(f"  drqv2 on {DISTRACTING}: background_dir {str(tmp_path / folder)!r} {expected}")
    assert "davischallenge.org" in errors[1]  # where to get the videos


def test_a_damaged_background_frame_is_named(tmp_path, capsys):
    for video in DAVIS_TRAIN_VIDEOS[:4]:  # the 'easy' background's videos
        (tmp_path / "davis" / video).mkdir(parents=True)
        (tmp_path / "davis" / video / "00000.jpg").write_bytes(b"not a jpeg")
    env_kwargs = {"distraction": "background", "background_dir": str(tmp_path / "davis")}
    status, errors = benchmark(tmp_path, capsys, block({"drqv2": {"hyperparams": SMALL}}, [DISTRACTING], env_kwargs))
    assert status == 2
    frame = tmp_path / "davis" / DAVIS_TRAIN_VIDEOS[0] / "00000.jpg"
    assert errors[1].startswith(f"  drqv2 on {DISTRACTING}: The background frame {str(frame)!r} cannot be decoded")


def test_every_bad_row_is_reported_and_a_run_refused_before_anything_trains(tmp_path, capsys):
    algorithms = {
        "drqv2": {"hyperparams": {**SMALL, "batch_size": 0}},
        "curl": {"hyperparams": SMALL, "env_kwargs": {"size": 64}},
        "drqv2_ef": {"hyperparams": SMALL},  # a good row
    }
    grid = block(algorithms, [TASK, "dmc/reacher-easy-v0"])
    for dry_run in (True, False):
        status, errors = benchmark(tmp_path, capsys, grid, dry_run=dry_run)
        assert status == 2
        assert errors[0] == "sb3-ef benchmark: error: 4 problems in the grid, nothing trained:"
        rows = [line.split(":")[0].strip() for line in errors[1:]]
        # yaml.safe_dump writes the labels sorted: curl first
        assert rows == [f"{label} on {task}" for label in ("curl", "drqv2") for task in (TASK, "dmc/reacher-easy-v0")]
        assert errors[3].endswith("DrQv2: batch_size must be a positive integer, got 0")
        assert not (tmp_path / "out").exists()


def test_bad_keys_of_several_blocks_are_all_reported(tmp_path, capsys):
    first = block({"drqv2": {"hyperparams": {"batch_sise": 8}}}, [TASK])
    second = block({"curl": {"hyperparams": {"beta": 1}}}, [TASK])
    status, errors = benchmark(tmp_path, capsys, first, second)
    assert status == 2
    assert len(errors) == 3
    assert (
        "grids[0]: hyperparams of 'drqv2': unknown key 'batch_sise' for drqv2 (did you mean 'batch_size'?)"
        in (errors[1])
    )
    assert "grids[1]: hyperparams of 'curl': unknown key 'beta' for curl" in errors[2]
