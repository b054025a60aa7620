"""Grid expansion: zoo entries + overrides -> runs, the grid file format, and bad grids refused early."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from sb3_ef.envs.tasks import DMC_PAPER_TASKS, METAWORLD_PAPER_TASKS
from sb3_ef.grid.grid import Algorithm, RunSpec, check_unique, grid_runs, load_grid, select_runs
from sb3_ef.grid.run import RunResult
from sb3_ef.grid.runner import plan_table, summary_table

HERE = Path(__file__).parent
TINY_GRID = HERE / "tiny_grid.yml"
REPO = HERE.parents[1]


def test_tiny_grid_expands_seeds_x_algorithms_x_tasks_over_the_zoo_entries():
    runs = load_grid(TINY_GRID)
    assert [run.run_id for run in runs] == [
        "drqv2/dmc-cartpole-balance-v0_s0",
        "drqv2_ef/dmc-cartpole-balance-v0_s0",
        "drqv2/dmc-cartpole-balance-v0_s1",
        "drqv2_ef/dmc-cartpole-balance-v0_s1",
    ]  # seed-major: a grid stopped part-way holds whole seeds
    drqv2, ef = runs[0], runs[1]
    # The overrides replace the entry's values; the other values come from zoo_configs/<algo>.yml's default entry.
    assert drqv2.hyperparams["batch_size"] == 8 and drqv2.hyperparams["learning_rate"] == 1e-4
    assert drqv2.hyperparams["exploration_std"] == "linear(1.0,0.1,500000)"
    assert ef.hyperparams["beta"] == 1.0 and ef.hyperparams["babbling_steps"] == 20
    assert "n_timesteps" not in drqv2.hyperparams  # the runner's key, not the constructor's
    assert (drqv2.n_timesteps, drqv2.eval_freq, drqv2.checkpoint_freq, drqv2.eval_episodes) == (200, 100, 100, 1)
    assert drqv2.env_kwargs == {"size": 32, "fast_render": True, "episode_length": 40}
    assert drqv2.action_repeat == 2  # make_env's default
    [toy] = grid_runs(["drqv2"], ["toy/agent-v0"], seeds=1, eval_freq=10, n_timesteps=20)
    assert toy.action_repeat == 1  # gym.make envs do not repeat actions


def test_entry_values_are_used_when_the_grid_does_not_override_them():
    [run] = grid_runs(["tdmpc2"], ["dmc/cheetah-run"], seeds=[7], eval_freq=5000, env_kwargs={"fast_render": True})
    assert run.task == "dmc/cheetah-run-v0"  # the registered id
    assert run.n_timesteps == 1_000_000  # the entry's n_timesteps
    assert run.env_kwargs == {"size": 64, "fast_render": True}  # the entry's env_kwargs, merged
    assert run.action_repeat == 2 and run.seed == 7


def test_labelled_variants_and_a_zoo_format_conf_file(tmp_path):
    conf = tmp_path / "mine.yml"
    conf.write_text(yaml.safe_dump({"default": {"policy": "CnnPolicy", "n_timesteps": 500, "batch_size": 16}}))
    runs = grid_runs(
        {
            "drqv2_ef": {},
            "drqv2_ef_beta1e-3": {"algo": "drqv2_ef", "hyperparams": {"beta": 1e-3}},
            "mine": {"algo": "drqv2", "conf_file": str(conf), "steps_per_second": 50},
        },
        ["dmc/reacher-easy"],
        seeds=1,
        eval_freq=100,
        n_timesteps=1000,
        hyperparams={"batch_size": 32},
    )
    assert [(run.label, run.algo) for run in runs] == [
        ("drqv2_ef", "drqv2_ef"),
        ("drqv2_ef_beta1e-3", "drqv2_ef"),
        ("mine", "drqv2"),
    ]
    assert runs[0].hyperparams["beta"] == 1.0 and runs[1].hyperparams["beta"] == 1e-3
    assert {run.hyperparams["batch_size"] for run in runs} == {32}  # the grid's override beats every entry
    assert runs[2].hyperparams == {"policy": "CnnPolicy", "batch_size": 32}
    assert runs[2].steps_per_second == 50


def _grid_file(tmp_path: Path, document: dict) -> Path:
    path = tmp_path / "grid.yml"
    path.write_text(yaml.safe_dump(document))
    return path


def _block(**changes) -> dict:
    block = {"algorithms": ["drqv2"], "tasks": ["toy/agent-v0"], "seeds": 1, "eval_freq": 10, "n_timesteps": 20}
    return {**block, **changes}


@pytest.mark.parametrize(
    ("document", "message"),
    [
        ({"grids": [_block(algorithms=["ppo_eff"])]}, "'ppo_eff' (did you mean 'ppo_ef' or 'ppo'?) is not a known"),
        ({"grids": [_block(algorithms=["ppo"], hyperparams={"n_envs": 0})]}, "'n_envs' must be a positive integer"),
        (
            {"grids": [_block(algorithms=["ppo"], tasks=["PongNoFrameskip-v4"], n_timesteps=100)]},
            "eval_freq (10) of ppo on PongNoFrameskip-v4 must be a multiple of its n_envs (8)",
        ),
        ({"grids": [_block(tasks=["dmc/cartpole-balanse"])]}, "Unknown task 'dmc/cartpole-balanse'"),
        ({"grids": [_block(hyperparams={"batch_sise": 8})]}, "unknown key 'batch_sise'"),
        ({"grids": [_block(hyperparams={"normalize": True})]}, "['normalize'] are not supported by the runner"),
        (
            {"grids": [_block(hyperparams={"policy_kwargs": "dict(net_arch=[32]"})]},
            "drqv2 on toy/agent-v0: SyntaxError",
        ),
        ({"grids": [_block(checkpoint_freq=15)]}, "checkpoint_freq (15) must be a multiple of eval_freq (10)"),
        ({"grids": [_block(eval_freq=40)]}, "eval_freq (40) exceeds n_timesteps (20)"),
        ({"grids": [_block(seeds=[0, "1"])]}, "'seeds' must be a positive count or a non-empty list of ints"),
        (
            {"grids": [_block(algorithms={"drqv2": {"lr": 1}})]},
            "Algorithm 'drqv2': unknown key(s) 'lr'; expected algo, conf_file",
        ),
        ({"grids": [_block(evaluation=1)]}, "grids[0]: unknown key(s) 'evaluation' (keys of a block: algorithms,"),
        ({"grids": [_block(eval_frq=10)]}, "unknown key(s) 'eval_frq' (did you mean 'eval_freq'?)"),
        ({"grids": [{"algorithms": ["drqv2"]}]}, "grids[0]: missing key(s) eval_freq, seeds, tasks (keys of"),
        ({"grids": [_block(tasks=["dmc/cartpole-balanse"])]}, "(did you mean 'dmc/cartpole-balance-v0'"),
        ({"grids": [_block(algorithms=["drqv2_fe"])]}, "algo 'drqv2_fe' (did you mean 'drqv2_ef'"),
        ({"grids": [_block(hyperparams=5)]}, "'hyperparams' must be a mapping of names to values, got 5"),
        ({"grids": [_block(tasks=5)]}, "'tasks' must be a list of gymnasium ids, got 5"),
        (
            {"grids": [_block(algorithms={"drqv2": {"env_kwargs": [1]}})]},
            "Algorithm 'drqv2': 'env_kwargs' must be a mapping of names to values, got [1]",
        ),
        (
            {"grids": [_block(), _block()]},
            "drqv2 on toy/agent-v0 with seed 0 is a run of {grid}, grids[0] and a run of {grid}, grids[1]: the two "
            "runs would share one results folder (drqv2/toy-agent-v0_s0); give drqv2 another label in one of them",
        ),
        (
            {"grids": [_block(seeds=[1, 1])]},
            "grid.yml, grids[0]: 'seeds' lists seed 1 twice ([1, 1]): one run per seed",
        ),
        (
            {"grids": [_block(tasks=["toy/agent", "toy/agent-v0"])]},
            "grids[0]: 'tasks' names toy/agent-v0 twice ('toy/agent' and 'toy/agent-v0'; the '-v0' may be left out)",
        ),
        (
            {"grids": [_block(algorithms=["drqv2", "drqv2"])]},
            "grids[0]: 'algorithms' lists 'drqv2' twice: give each variant its own label (label -> options)",
        ),
        ({"grids": [_block()], "grid": []}, "unknown top-level key(s) 'grid' (did you mean 'grids'?)"),
        ({"grid": [_block()]}, "non-empty list 'grids'"),
    ],
)
def test_bad_grids_are_refused_with_the_cause_named(tmp_path, document, message):
    path = _grid_file(tmp_path, document)
    with pytest.raises(ValueError) as error:
        load_grid(path)
    assert message.format(grid=path) in str(error.value)


def test_runs_given_together_from_python_are_refused_when_two_share_an_id():
    runs = load_grid(TINY_GRID)
    with pytest.raises(ValueError, match=r"drqv2 on dmc/cartpole-balance-v0 with seed 0 is run 1 of the grid and run"):
        check_unique([*runs, runs[0]])


def test_runs_are_selected_by_shell_patterns_on_their_ids():
    runs = load_grid(TINY_GRID)
    assert [run.run_id for run in select_runs(runs, ["*_s1"])] == [runs[2].run_id, runs[3].run_id]
    assert select_runs(runs, ["drqv2_ef/*", "drqv2/*_s0"]) == [runs[0], runs[1], runs[3]]
    with pytest.raises(ValueError, match="No run id matches \\['ppo/\\*'\\]; ids look like 'drqv2/dmc-cartpole"):
        select_runs(runs, ["ppo/*"])


def test_an_algorithm_label_cannot_be_a_path():
    with pytest.raises(ValueError, match="without '/'"):
        Algorithm("drqv2/ef", algo="drqv2_ef")


def test_paper_grid_covers_the_papers_tasks_at_its_budgets_with_expected_hours(tmp_path):
    runs = load_grid(REPO / "benchmarks" / "paper_grid.yml")
    by_algorithm: dict[str, set[str]] = {}
    for run in runs:
        by_algorithm.setdefault(run.label, set()).add(run.task)
    dmc = {f"dmc/{task}-v0" for task in DMC_PAPER_TASKS}
    metaworld = {f"metaworld/{task}-v0" for task in METAWORLD_PAPER_TASKS}
    suite = ("ball-in-cup-catch", "cartpole-swingup", "cheetah-run", "finger-spin", "reacher-easy", "walker-walk")
    distracting = {f"dmc-distracting/{task}-v0" for task in suite}
    assert by_algorithm == {
        "drqv2": dmc | metaworld | distracting,
        "drqv2_ef": dmc | metaworld | distracting,
        "drqv2_ef_latent": distracting,
        "tdmpc2": dmc,
        "tdmpc2_ef": dmc,
        "sear": dmc | metaworld,
        "curl": dmc,
        "dreamerv3": dmc,
    }
    assert {run.seed for run in runs} == set(range(5))
    for run in runs:
        on_dmc = run.task.startswith(("dmc/", "dmc-distracting/"))
        frames = run.n_timesteps * run.action_repeat
        assert frames == (1_000_000 if on_dmc else 2_500_000), run.run_id
        assert run.eval_freq * run.action_repeat == (10_000 if on_dmc else 5_000)
        assert run.eval_episodes == 10 and run.steps_per_second is not None
    # The dry-run table sums n_timesteps / steps_per_second over the runs.
    expected = sum(run.n_timesteps / run.steps_per_second for run in runs) / 3600
    assert plan_table(runs, tmp_path).splitlines()[-1].split()[-1] == f"{expected:.1f}"


def test_summary_table_gives_mean_and_std_over_finished_seeds_and_a_lone_run_alone():
    specs = [RunSpec(label, "drqv2", "dmc/cartpole-balance-v0", seed, 100, 50, 1, 50)
             for label in ("drqv2", "drqv2_ef") for seed in (0, 1)]  # fmt: skip
    results = [
        RunResult(specs[0].run_id, "done", 100, 1800.0, 250.0),
        RunResult(specs[1].run_id, "skipped", 100, 1800.0, 270.0),
        RunResult(specs[2].run_id, "done", 100, 3600.0, 300.0),
        RunResult(specs[3].run_id, "failed", error="RuntimeError: boom"),
    ]
    rows = [line.split() for line in summary_table(specs, results).splitlines()[2:]]
    assert rows == [
        ["drqv2", "dmc/cartpole-balance-v0", "2/2", "0", "260.0", "+-", "14.1", "1.00"],
        ["drqv2_ef", "dmc/cartpole-balance-v0", "1/2", "1", "300.0", "1.00"],
    ]
