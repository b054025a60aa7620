"""``sb3-ef analyze``: tables and plots from evaluation CSVs, or predictions and saliency of a saved model.

sb3-ef analyze results DIR [--out DIR] [--return-scale 1000] [--reps 2000] [--at STEP ...] [--finished-only]
                        [--reference drqv2|tdmpc2]
sb3-ef analyze model PATH --env NAME [--algo drqv2_ef|tdmpc2_ef] [--steps T] [--actions policy|figure8]
                                     [--action-repeat 2] [--env-kwargs key:value ...] [--seed 0] [--out DIR]

``analyze model`` builds the env the model was trained on: rendering settings such as ``fast_render`` change the
frames, so they come from ``--env-kwargs`` or, for a model inside an rl-zoo3 run folder, from the run's
``<env>/args.yml`` and ``<env>/config.yml``.
"""

from __future__ import annotations

import argparse
import ast
import json
import os
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

#: Algorithms ``analyze model`` can load, by the keys of the rl-zoo plug-in, and their public class names.
EF_ALGORITHMS = {"drqv2_ef": "DrQv2EF", "tdmpc2_ef": "TDMPC2EF"}
#: Replay-buffer capacity (frames) given to a model loaded for analysis: it never trains.
ANALYSIS_BUFFER_SIZE = 256


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="sb3-ef analyze", description=__doc__.split("\n")[0])
    commands = parser.add_subparsers(dest="command", required=True)

    results = commands.add_parser("results", help="ENS, rliable metrics and plots from every eval CSV under DIR")
    results.add_argument("directory", help="directory searched recursively for evaluation CSVs")
    results.add_argument("--out", help="output directory (default: DIR/analysis)")
    results.add_argument("--return-scale", type=float, default=1000.0, help="returns are divided by this (DMC: 1000)")
    results.add_argument("--reps", type=int, default=2000, help="bootstrap resamples for the confidence intervals")
    results.add_argument(
        "--at", type=int, nargs="+", metavar="STEP", help="also tabulate mean +- std return at these steps"
    )
    results.add_argument(
        "--finished-only",
        action="store_true",
        help="only finished runs of an `sb3-ef benchmark` folder (those with a result.json), not runs in progress",
    )
    results.add_argument(
        "--reference",
        choices=("drqv2", "tdmpc2"),
        help="put the runs beside published curves: DrQ-v2's official DMC curves or TD-MPC2's DMC pixel results",
    )

    model = commands.add_parser("model", help="open-loop prediction, saliency and mask scores of a saved model")
    model.add_argument("path", help="saved model (.zip)")
    model.add_argument("--env", required=True, help="env name, e.g. dmc/reacher-easy, metaworld/hammer, toy/agent-v0")
    model.add_argument("--algo", choices=sorted(EF_ALGORITHMS), help="algorithm (default: tried in turn)")
    model.add_argument("--steps", type=int, help="prediction length T (default: the EF horizon)")
    model.add_argument("--actions", choices=("policy", "figure8"), default="policy", help="actions played")
    model.add_argument("--action-repeat", type=int, default=2, help="action repeat of dmc/ and metaworld/ envs")
    model.add_argument(
        "--env-kwargs",
        nargs="+",
        default=None,
        metavar="KEY:VALUE",
        help="make_env options of the training env, e.g. fast_render:True (default: the run's, if recorded)",
    )
    model.add_argument("--seed", type=int, default=0, help="env reset seed")
    model.add_argument("--out", help="output directory (default: next to the model, <name>_analysis)")
    return parser


def parse_env_kwargs(pairs: list[str]) -> dict[str, Any]:
    """``["size:64", "fast_render:True"]`` -> ``{"size": 64, "fast_render": True}`` (values as Python literals,
    else strings), as rl-zoo3 writes ``--env-kwargs``."""
    kwargs = {}
    for pair in pairs:
        key, separator, value = pair.partition(":")
        if not separator or not key:
            raise ValueError(f"--env-kwargs expects key:value pairs (e.g. fast_render:True), got {pair!r}")
        try:
            kwargs[key] = ast.literal_eval(value)
        except (ValueError, SyntaxError):
            kwargs[key] = value
    return kwargs


def run_env_kwargs(model_path: str | os.PathLike) -> dict[str, Any]:
    """The env options of the rl-zoo3 run whose folder holds ``model_path`` (``{}`` elsewhere). As in rl-zoo3's
    train and enjoy, the command line's ``--env-kwargs`` (``<env>/args.yml``) replace the config entry's
    (``<env>/config.yml``)."""
    import yaml

    folder = Path(model_path).resolve().parent
    args_files = sorted(folder.glob("*/args.yml"))
    if len(args_files) != 1:
        return {}
    with open(args_files[0]) as file:
        args = yaml.load(file, Loader=yaml.UnsafeLoader)  # an OrderedDict (Python tags)
    if args.get("env_kwargs"):
        return dict(args["env_kwargs"])
    config_path = args_files[0].with_name("config.yml")
    if not config_path.is_file():
        return {}
    with open(config_path) as file:
        entry = dict(yaml.load(file, Loader=yaml.UnsafeLoader) or [])  # rl-zoo3 writes a list of pairs
    recorded = entry.get("env_kwargs") or {}
    if isinstance(recorded, str):  # rl-zoo3 evaluates strings such as "dict(size=64)"
        recorded = eval(recorded, {"__builtins__": {}, "dict": dict})
    return dict(recorded)


def analyze_results(
    directory: str,
    out: str,
    return_scale: float = 1000.0,
    reps: int = 2000,
    at: tuple[int, ...] = (),
    finished_only: bool = False,
    reference: str | None = None,
) -> dict[str, Any]:
    """Write ``scores.csv``, ``ens.csv``, ``ens_details.csv``, ``rliable.csv`` and the plots to ``out`` (created
    only once the records have been read), and ``returns_at.csv`` for the steps ``at``; ``finished_only`` reads
    only the finished runs of an ``sb3-ef benchmark`` folder. With ``reference`` (``drqv2`` or ``tdmpc2``), also the
    published curves beside the runs (``reference_<name>_<task>.png``) and ``reference_<name>.csv``: your mean at
    each step of ``at`` (default: the last step all seeds reached) against the official mean and min-max.

    A grid part-way through is analysed as far as it allows: ENS over the tasks that every algorithm has results
    on, rliable metrics only when each algorithm has as many seeds on every task; what is left out is printed.
    """
    from sb3_ef.analysis.metrics import (
        efficiency_normalized_score,
        ens_table,
        load_records,
        records_to_scores,
        returns_at,
        rliable_metrics,
        tasks_with_every_algorithm,
        uneven_seed_counts,
    )
    from sb3_ef.analysis.plots import plot_ens, plot_intervals, plot_learning_curves

    if not os.path.isdir(directory):
        what = "is a file, not a folder" if os.path.exists(directory) else "does not exist"
        raise FileNotFoundError(f"The results folder {directory!r} {what}: pass the folder holding the evaluation CSVs")
    records = load_records(directory, finished_only)
    scores = records_to_scores(records, return_scale=return_scale)
    at_steps = returns_at(records, tuple(at)) if at else None
    os.makedirs(out, exist_ok=True)
    scores.to_csv(os.path.join(out, "scores.csv"), index=False)
    written: dict[str, Any] = {"curves": plot_learning_curves(scores, out)}
    print(f"Scores of {scores['algo'].nunique()} algorithm(s) on {scores['task'].nunique()} task(s) -> {out}")
    shared = tasks_with_every_algorithm(scores)
    if scores["algo"].nunique() < 2:
        print("ENS compares algorithms: skipped with a single algorithm")
    elif not shared:
        print("ENS skipped: no task has results of every algorithm")
    else:
        left_out = sorted(set(scores["task"]) - set(shared))
        if left_out:
            print(f"ENS over {shared} only; left out, without results of every algorithm: {left_out}")
        ens_scores = scores[scores["task"].isin(shared)]
        ens_table(ens_scores).to_csv(os.path.join(out, "ens_details.csv"), index=False)
        ens = efficiency_normalized_score(ens_scores)
        ens.to_csv(os.path.join(out, "ens.csv"))
        written["ens"] = plot_ens(ens, os.path.join(out, "ens.png"))
        print(ens.to_string())
    uneven = uneven_seed_counts(scores)
    if uneven:
        print(f"rliable metrics skipped: they need as many seeds on every task, seeds per task: {uneven}")
    else:
        table = rliable_metrics(scores, reps=reps)
        table.to_csv(os.path.join(out, "rliable.csv"), index=False)
        written["rliable"] = plot_intervals(table, os.path.join(out, "rliable.png"))
        print(table.to_string(index=False))
    if at_steps is not None:
        at_steps.to_csv(os.path.join(out, "returns_at.csv"), index=False)
        print(at_steps.to_string(index=False, float_format="%.1f"))
    if reference is not None:
        written.update(compare_with_reference(records, reference, out, tuple(at)))
    return written


def compare_with_reference(records: Any, name: str, out: str, at: tuple[int, ...]) -> dict[str, Any]:
    """Write and print the table and curves of your runs beside a published reference."""
    from sb3_ef.analysis.plots import plot_reference_curves
    from sb3_ef.analysis.reference import get_reference, missing_tasks, reference_table

    reference = get_reference(name)
    missing = missing_tasks(records, name)
    if missing:
        print(f"No {reference.label} curves for {missing}: left out of the comparison")
    table = reference_table(records, name, at)
    path = os.path.join(out, f"reference_{name}.csv")
    table.to_csv(path, index=False)
    print(f"Against {reference.label} ({reference.source}), x in {reference.unit}:")
    print(table.to_string(index=False, float_format="%.1f") if not table.empty else "no task in common")
    return {"reference_table": path, "reference_curves": plot_reference_curves(records, name, out)}


def make_analysis_env(
    name: str,
    frame_shape: tuple[int, ...],
    frame_stack: int,
    action_repeat: int,
    env_kwargs: dict[str, Any] | None = None,
) -> gym.Env:
    """The model's env at its frame size: ``make_env`` for dmc/ and metaworld/ names, ``gym.make`` otherwise.

    :param env_kwargs: the other options of the training env (``fast_render``, ``camera``, ...); its ``size`` and
        ``frame_stack`` must agree with the model's.
    """
    kwargs = dict(env_kwargs or {})
    size = frame_shape[-1]
    for key, expected in (("size", size), ("frame_stack", frame_stack)):
        value = kwargs.pop(key, expected)
        if value != expected:
            raise ValueError(f"env_kwargs {key}={value!r} does not match the model's {key} {expected}")
    if name.startswith(("dmc/", "metaworld/")):
        from sb3_ef.envs import make_env

        return make_env(name, size=size, frame_stack=frame_stack, **{"action_repeat": action_repeat, **kwargs})
    return gym.make(name, size=size, frame_stack=frame_stack, **kwargs)


def load_ef_model(path: str, algo: str | None) -> Any:
    """Load a saved DrQv2EF / TDMPC2EF (``algo`` given, or each tried in turn) with a tiny replay buffer."""
    import sb3_ef

    errors = []
    for key in [algo] if algo else list(EF_ALGORITHMS):
        algo_class = getattr(sb3_ef, EF_ALGORITHMS[key])
        try:
            return algo_class.load(path, buffer_size=ANALYSIS_BUFFER_SIZE, device="auto")
        except Exception as error:  # report why every candidate failed, not just the last
            errors.append(f"{key}: {type(error).__name__}: {error}")
    raise ValueError(f"Could not load {path} as {' or '.join(EF_ALGORITHMS)}:\n" + "\n".join(errors))


def analyze_model(
    path: str,
    env_name: str,
    out: str,
    algo: str | None = None,
    steps: int | None = None,
    actions: str = "policy",
    action_repeat: int = 2,
    seed: int = 0,
    env_kwargs: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Write ``prediction.png`` (context / predicted / true rows), ``prediction.gif`` (predicted | true),
    ``saliency.png`` and ``scores.json`` for one rollout of a saved model on ``env_name``, built with
    ``env_kwargs`` (default: :func:`run_env_kwargs`)."""
    from sb3_ef.analysis.plots import plot_prediction, plot_saliency
    from sb3_ef.analysis.prediction import figure_eight_actions, save_video
    from sb3_ef.analysis.report import foresight_report, record_rollout

    model = load_ef_model(path, algo)
    if getattr(model, "ef", None) is None:
        raise ValueError(f"{path} is a {type(model).__name__} without Ego-Foresight: nothing to analyze")
    frame_stack = model.observation_space.shape[0] // 3
    if env_kwargs is None:
        env_kwargs = run_env_kwargs(path)
    env = make_analysis_env(env_name, model.frame_shape, frame_stack, action_repeat, env_kwargs)
    steps = steps or model.ef.horizon
    if actions == "figure8":
        sequence = figure_eight_actions(steps, model.action_space.shape[0])
        act = lambda _observation, step: sequence[step]  # noqa: E731
    else:
        act = lambda observation, _step: model.predict(observation, deterministic=True)[0]  # noqa: E731
    try:
        report = foresight_report(model, record_rollout(env, act, steps, seed=seed))
    finally:
        env.close()
    os.makedirs(out, exist_ok=True)
    title = f"{type(model).__name__} on {env_name}, {actions} actions"
    written = {
        "prediction": plot_prediction(report, os.path.join(out, "prediction.png"), title),
        "video": save_video(os.path.join(out, "prediction.gif"), report.predicted, report.rollout.true_frames),
        "saliency": plot_saliency(report, os.path.join(out, "saliency.png"), f"{title}, t+{len(report.predicted)}"),
    }
    scores = {
        "env": env_name,
        "env_kwargs": env_kwargs,
        "steps": len(report.predicted),
        "actions": actions,
        **report.scalars(),
    }
    written["scores"] = os.path.join(out, "scores.json")
    with open(written["scores"], "w") as file:
        json.dump(
            {key: None if isinstance(value, float) and np.isnan(value) else value for key, value in scores.items()},
            file,
            indent=2,
        )
    print(json.dumps(scores, indent=2))
    print(f"Wrote {', '.join(os.path.basename(path) for path in written.values())} to {out}")
    return written


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``sb3-ef analyze``; returns the exit status."""
    args = build_parser().parse_args(argv)
    if args.command == "results":
        analyze_results(
            args.directory,
            args.out or os.path.join(args.directory, "analysis"),
            args.return_scale,
            args.reps,
            tuple(args.at or ()),
            args.finished_only,
            args.reference,
        )
    else:
        out = args.out or os.path.splitext(args.path)[0] + "_analysis"
        env_kwargs = None if args.env_kwargs is None else parse_env_kwargs(args.env_kwargs)
        analyze_model(
            args.path, args.env, out, args.algo, args.steps, args.actions, args.action_repeat, args.seed, env_kwargs
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
