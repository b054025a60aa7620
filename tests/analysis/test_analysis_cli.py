import json

import numpy as np
import pandas as pd
import pytest
from PIL import Image

from sb3_ef import DrQv2EF
from sb3_ef.analysis.cli import main
from sb3_ef.analysis.records import append_records
from sb3_ef.envs.toy import ToyAgentEnv
from sb3_ef.grid.run import RunPaths, RunResult, store_result

TINY_DRQV2 = {
    "features_dim": 64,
    "agent_dim": 8,
    "net_arch": [32, 32],
    "trunk_dim": 16,
    "ef_kwargs": {"rollout_hidden_dims": (16,), "decoder_channels": 8},
}


def write_results(directory):
    rng = np.random.default_rng(0)
    for algo, slope in (("DrQv2EF", 2.0), ("DrQv2", 1.0)):
        for seed in (0, 1):
            rows = [
                {"algo": algo, "task": task, "seed": seed, "step": step, "frame": 2 * step,
                 "return": slope * step + rng.uniform(0, 10), "success": ""}
                for task in ("dmc/reacher-easy", "dmc/cartpole-swingup")
                for step in (0, 100, 200, 300)
            ]  # fmt: skip
            append_records(directory / algo / f"seed{seed}.csv", rows)


def test_results_command_writes_tables_and_plots(tmp_path, capsys):
    write_results(tmp_path / "runs")
    assert main(["results", str(tmp_path / "runs"), "--out", str(tmp_path / "out"), "--reps", "20"]) == 0
    out = tmp_path / "out"
    names = {path.name for path in out.iterdir()}
    assert {"scores.csv", "ens.csv", "ens_details.csv", "rliable.csv", "ens.png", "rliable.png"} <= names
    assert {"curve_dmc_reacher-easy.png", "curve_dmc_cartpole-swingup.png"} <= names
    ens = dict(line.split(",") for line in (out / "ens.csv").read_text().splitlines()[1:])
    # the faster learner (slope 2) sets the thresholds and scores about 1; the slower one about half of that
    assert float(ens["DrQv2EF"]) > 0.9 and 0.3 < float(ens["DrQv2"]) < 0.7
    assert "IQM" in capsys.readouterr().out


def test_results_command_tabulates_returns_at_steps(tmp_path):
    write_results(tmp_path / "runs")
    out = tmp_path / "out"
    assert main(["results", str(tmp_path / "runs"), "--out", str(out), "--reps", "20", "--at", "200", "300"]) == 0
    table = pd.read_csv(out / "returns_at.csv")
    assert len(table) == 2 * 2 * 2  # algorithms x tasks x steps
    assert set(table["seeds"]) == {2}
    slow = table[(table.algo == "DrQv2") & (table.task == "dmc/reacher-easy") & (table.step == 300)]
    assert 300 <= slow["mean"].item() <= 310  # slope 1 plus uniform(0, 10) noise


def test_results_of_a_grid_part_way_through_are_analysed_as_far_as_they_go(tmp_path, capsys):
    write_results(tmp_path / "runs")
    rows = [{"algo": "DrQv2", "task": "dmc/walker-walk", "seed": 0, "step": 100, "frame": 200, "return": 50.0,
             "success": ""}]  # fmt: skip
    append_records(tmp_path / "runs" / "DrQv2" / "walker.csv", rows)  # one algorithm, one seed so far
    out = tmp_path / "out"
    assert main(["results", str(tmp_path / "runs"), "--out", str(out), "--reps", "20"]) == 0
    printed = capsys.readouterr().out
    assert "left out, without results of every algorithm: ['dmc/walker-walk']" in printed
    assert set(pd.read_csv(out / "ens_details.csv")["task"]) == {"dmc/reacher-easy", "dmc/cartpole-swingup"}
    assert (out / "curve_dmc_walker-walk.png").exists()
    assert "ENS and rliable over ['dmc/cartpole-swingup', 'dmc/reacher-easy'] only" in printed
    # rliable over the two shared tasks: DrQv2's single walker-walk run (best 0.05) is not among the scores
    drqv2_iqm = pd.read_csv(out / "rliable.csv").query("algo == 'DrQv2' and metric == 'IQM'")["estimate"].item()
    assert 0.3 <= drqv2_iqm <= 0.31  # best scores 0.3-0.31 on both shared tasks (slope 1, 300 steps)


def test_results_skip_rliable_when_seed_counts_differ_between_shared_tasks(tmp_path, capsys):
    write_results(tmp_path / "runs")
    rows = [{"algo": algo, "task": "dmc/walker-walk", "seed": 0, "step": 100, "frame": 200, "return": 50.0,
             "success": ""} for algo in ("DrQv2", "DrQv2EF")]  # fmt: skip
    append_records(tmp_path / "runs" / "walker.csv", rows)  # both algorithms, one seed where the others have two
    out = tmp_path / "out"
    assert main(["results", str(tmp_path / "runs"), "--out", str(out), "--reps", "20"]) == 0
    printed = capsys.readouterr().out
    assert "rliable metrics skipped" in printed and "'dmc/walker-walk': 1" in printed
    assert not (out / "rliable.csv").exists() and (out / "ens.csv").exists()


def test_results_of_finished_runs_only_leave_runs_in_progress_out(tmp_path, capsys):
    write_results(tmp_path / "runs")
    for csv in (tmp_path / "runs").rglob("*.csv"):  # finished, as `sb3-ef benchmark` marks a run
        store_result(RunPaths(records=csv, folder=csv.with_suffix("")), RunResult(run_id=csv.stem, status="done"))
    rows = [{"algo": "DrQv2", "task": "dmc/walker-walk", "seed": 0, "step": 100, "frame": 200, "return": 50.0,
             "success": ""}]  # fmt: skip
    append_records(tmp_path / "runs" / "DrQv2" / "walker.csv", rows)  # a run in progress: no result.json yet
    append_records(tmp_path / "in_progress" / "walker.csv", rows)
    out = tmp_path / "out"
    assert main(["results", str(tmp_path / "runs"), "--out", str(out), "--reps", "20", "--finished-only"]) == 0
    assert "dmc/walker-walk" not in capsys.readouterr().out
    assert set(pd.read_csv(out / "scores.csv")["task"]) == {"dmc/reacher-easy", "dmc/cartpole-swingup"}
    assert (out / "rliable.csv").exists()  # even seeds once the run in progress is left out
    with pytest.raises(FileNotFoundError, match=r"of a finished run \(result.json beside it\)"):
        main(["results", str(tmp_path / "in_progress"), "--finished-only"])


def test_results_command_without_records_fails_clearly(tmp_path):
    with pytest.raises(FileNotFoundError, match="No evaluation CSV"):
        main(["results", str(tmp_path)])
    assert list(tmp_path.iterdir()) == []  # no analysis/ folder left behind


def test_model_command_writes_prediction_saliency_and_scores(tmp_path, capsys):
    model = DrQv2EF("CnnPolicy", ToyAgentEnv(size=32), buffer_size=100, batch_size=4, learning_starts=8,
                    ef_horizon=3, babbling_steps=0, policy_kwargs=TINY_DRQV2, device="cpu")  # fmt: skip
    model.learn(10)
    model.save(tmp_path / "model.zip")
    out = tmp_path / "analysis"
    status = main(["model", str(tmp_path / "model.zip"), "--env", "toy/agent-v0", "--steps", "5",
                   "--actions", "figure8", "--out", str(out)])  # fmt: skip
    assert status == 0
    assert f"Wrote prediction.png, prediction.gif, saliency.png, scores.json to {out}" in capsys.readouterr().out
    # Labelled figures: larger than the bare frame grids (5 x 3 and 3 x 1 frames of 32 pixels, 2-pixel spacing).
    assert Image.open(out / "prediction.png").size > (5 * 32 + 8, 3 * 32 + 4)
    assert Image.open(out / "saliency.png").size > (3 * 32 + 4, 32)
    assert (out / "prediction.gif").stat().st_size > 0
    scores = json.loads((out / "scores.json").read_text())
    assert scores["steps"] == 5 and {"prediction_mse", "mask_precision", "mask_recall", "mask_iou"} <= set(scores)
    with pytest.raises(SystemExit):
        main(["model", str(tmp_path / "model.zip")])  # --env is required


def _write_zoo_run(folder, env_name, command_line_kwargs, config_kwargs):
    """The two files of an rl-zoo3 run that record env options, in rl-zoo3's own YAML layout."""
    from collections import OrderedDict

    import yaml

    (folder / env_name).mkdir(parents=True)
    with open(folder / env_name / "args.yml", "w") as file:
        yaml.dump(OrderedDict([("env", env_name), ("env_kwargs", command_line_kwargs)]), file)
    with open(folder / env_name / "config.yml", "w") as file:
        yaml.dump(OrderedDict([("env_kwargs", config_kwargs), ("policy", "CnnPolicy")]), file)


def test_run_env_kwargs_come_from_the_zoo_run_folder(tmp_path):
    from sb3_ef.analysis.cli import parse_env_kwargs, run_env_kwargs

    _write_zoo_run(tmp_path / "cli", "dmc-reacher-easy-v0", {"fast_render": True}, {"fast_render": True})
    assert run_env_kwargs(tmp_path / "cli" / "dmc-reacher-easy-v0.zip") == {"fast_render": True}
    _write_zoo_run(tmp_path / "config", "dmc-reacher-easy-v0", None, "dict(size=64, fast_render=True)")
    assert run_env_kwargs(tmp_path / "config" / "dmc-reacher-easy-v0.zip") == {"size": 64, "fast_render": True}
    assert run_env_kwargs(tmp_path / "elsewhere" / "model.zip") == {}
    assert parse_env_kwargs(["fast_render:True", "size:64", "camera:corner"]) == {
        "fast_render": True,
        "size": 64,
        "camera": "corner",
    }
    with pytest.raises(ValueError, match="key:value"):
        parse_env_kwargs(["fast_render"])


def test_model_command_on_a_one_dimensional_action_task_with_the_runs_rendering(tmp_path, capsys):
    """Cartpole has one action dimension; the run trained with fast_render, so the analysis renders that way too."""
    from sb3_ef import make_env

    model = DrQv2EF("CnnPolicy", make_env("dmc/cartpole-swingup", size=32, fast_render=True), buffer_size=100,
                    batch_size=4, learning_starts=8, ef_horizon=3, babbling_steps=0, policy_kwargs=TINY_DRQV2,
                    device="cpu")  # fmt: skip
    model.learn(10)
    _write_zoo_run(tmp_path, "dmc-cartpole-swingup-v0", {"fast_render": True}, None)
    model.save(tmp_path / "dmc-cartpole-swingup-v0.zip")
    out = tmp_path / "analysis"
    main(["model", str(tmp_path / "dmc-cartpole-swingup-v0.zip"), "--env", "dmc/cartpole-swingup", "--steps", "3",
          "--actions", "figure8", "--out", str(out)])  # fmt: skip
    scores = json.loads((out / "scores.json").read_text())
    assert scores["env_kwargs"] == {"fast_render": True} and scores["steps"] == 3
    with pytest.raises(ValueError, match="does not match the model's size 32"):
        main(["model", str(tmp_path / "dmc-cartpole-swingup-v0.zip"), "--env", "dmc/cartpole-swingup",
              "--env-kwargs", "size:64", "--out", str(out)])  # fmt: skip


def _zoo_task_names():
    import yaml

    from sb3_ef.zoo.config import default_config_path

    names = set()
    for algo in ("drqv2_ef", "tdmpc2_ef"):
        with open(default_config_path(algo)) as file:
            names |= {name.removesuffix("-v0") for name in yaml.safe_load(file) if name != "default"}
    return sorted(names)


def _first_frame(env):
    try:
        observation, _ = env.reset(seed=0)
    finally:
        env.close()
    return observation[-3:].astype(np.int16)


def _analysis_frame_of_a_fast_render_run(tmp_path, name):
    from sb3_ef.analysis.cli import make_analysis_env, run_env_kwargs

    run = tmp_path / name.replace("/", "-")
    _write_zoo_run(run, "env", {"fast_render": True, "size": 32}, None)
    kwargs = run_env_kwargs(run / "model.zip")
    return _first_frame(make_analysis_env(name, (3, 32, 32), 3, 2, env_kwargs={**kwargs, "seed": 0}))


def test_analysis_renders_like_the_run_where_fast_render_changes_the_frames(tmp_path):
    """reacher-easy: without its shadows the frame differs by ~28 grey levels; the analysis env renders as trained."""
    from sb3_ef import make_env

    trained = _first_frame(make_env("dmc/reacher-easy", size=32, fast_render=True, seed=0))
    default = _first_frame(make_env("dmc/reacher-easy", size=32, seed=0))
    assert np.abs(trained - default).mean() > 10
    assert np.array_equal(_analysis_frame_of_a_fast_render_run(tmp_path, "dmc/reacher-easy"), trained)


@pytest.mark.slow
def test_analysis_renders_like_the_run_on_every_zoo_task(tmp_path):
    """The 12 DMC and 16 Meta-World tasks of zoo_configs/, one first frame each (about a minute on 2 cores)."""
    from sb3_ef import make_env

    names = _zoo_task_names()
    assert len(names) == 28
    for name in names:
        trained = _first_frame(make_env(name, size=32, fast_render=True, seed=0))
        assert np.array_equal(_analysis_frame_of_a_fast_render_run(tmp_path, name), trained), name


def _sac_ef():
    from sb3_ef import SACEF
    from sb3_ef.drqv2.policies import DrQv2Encoder

    policy = {"net_arch": [16], "normalize_images": False, "features_extractor_class": DrQv2Encoder,
              "features_extractor_kwargs": {"features_dim": 32}}  # fmt: skip
    ef_kwargs = {"rollout_hidden_dims": (8,), "decoder_channels": 4}
    return SACEF("CnnPolicy", ToyAgentEnv(size=32), buffer_size=100, ef_horizon=3, agent_dim=8, ef_kwargs=ef_kwargs,
                 policy_kwargs=policy, device="cpu")  # fmt: skip


def test_model_command_loads_the_algorithm_the_file_records(tmp_path, capsys):
    """A SACEF file: loaded as SACEF (no --algo, which once tried DrQv2EF and TDMPC2EF only) and analysed."""
    _sac_ef().save(tmp_path / "sac_ef.zip")
    out = tmp_path / "analysis"
    argv = ["model", str(tmp_path / "sac_ef.zip"), "--env", "toy/agent-v0", "--steps", "3", "--out", str(out)]
    assert main(argv) == 0
    assert f"Wrote prediction.png, prediction.gif, saliency.png, scores.json to {out}" in capsys.readouterr().out
    scores = json.loads((out / "scores.json").read_text())
    assert scores["steps"] == 3 and "prediction_mse" in scores
    assert sorted(path.name for path in out.iterdir()) == ["prediction.gif", "prediction.png", "saliency.png",
                                                           "scores.json"]  # fmt: skip


def _without_ef(name):
    from sb3_ef import CURL
    from tests.helpers.sear import make_sear

    if name == "SEAR":
        return make_sear()
    return CURL("CnnPolicy", ToyAgentEnv(size=40), crop_size=32, features_dim=16, buffer_size=100,
                policy_kwargs={"net_arch": [16]}, device="cpu")  # fmt: skip


@pytest.mark.parametrize("name", ["SEAR", "CURL"])
def test_model_command_on_an_algorithm_without_ef_says_what_to_do(name, tmp_path, capsys, monkeypatch):
    from sb3_ef import cli

    _without_ef(name).save(tmp_path / "model.zip")
    monkeypatch.delenv("SB3_EF_TRACEBACK", raising=False)
    status = cli.main(["analyze", "model", str(tmp_path / "model.zip"), "--env", "toy/agent-v0"])
    err = capsys.readouterr().err
    assert status == 2 and "Traceback" not in err and f"{name}.load" not in err
    [line] = err.strip().splitlines()
    assert f"holds a {name} model, which has no Ego-Foresight module" in line
    assert "DrQv2EF, TDMPC2EF, SACEF, TD3EF, TQCEF" in line and "sb3-ef analyze results" in line
    assert sorted(path.name for path in tmp_path.iterdir()) == ["model.zip"]


def test_model_command_refuses_an_algo_that_contradicts_the_file(tmp_path):
    model = DrQv2EF("CnnPolicy", ToyAgentEnv(size=32), buffer_size=100, ef_horizon=3, babbling_steps=0,
                    policy_kwargs=TINY_DRQV2, device="cpu")  # fmt: skip
    model.save(tmp_path / "model.zip")
    with pytest.raises(ValueError, match=r"--algo sac_ef \(SACEF\) does not match .*model.zip, which DrQv2EF saved"):
        main(["model", str(tmp_path / "model.zip"), "--env", "toy/agent-v0", "--algo", "sac_ef"])
    with pytest.raises(ValueError, match=r"steps \(--steps\) must be a positive whole number, got 0"):
        main(["model", str(tmp_path / "model.zip"), "--env", "toy/agent-v0", "--steps", "0"])
    with pytest.raises(FileNotFoundError, match="No saved model at"):
        main(["model", str(tmp_path / "missing.zip"), "--env", "toy/agent-v0"])
    assert sorted(path.name for path in tmp_path.iterdir()) == ["model.zip"]
