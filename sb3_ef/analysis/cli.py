"""``sb3-ef analyze``: tables and plots from evaluation CSVs, or predictions and saliency of a saved model.
``analyze model`` builds the env the model trained on: its options from ``--env-kwargs`` or the model's run folder."""

from __future__ import annotations

import argparse
import ast
import json
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

import gymnasium as gym
import numpy as np

from sb3_ef import registry
from sb3_ef.common.acting import EpisodeActor
from sb3_ef.common.files import write_text_atomically
from sb3_ef.envs.factory import MAKE_ENV_SUITES
from sb3_ef.envs.registration import is_atari

if TYPE_CHECKING:
    from stable_baselines3.common.base_class import BaseAlgorithm

#: The Ego-Foresight algorithms ``analyze model`` shows (``sb3_ef.registry``), by key, and their class names.
EF_ALGORITHMS = {key: registry.entry(key).class_name for key in registry.keys(ef=True)}
#: The published references of ``analyze results --reference`` (``sb3_ef.analysis.reference.REFERENCES``).
REFERENCE_NAMES = ("drqv2", "tdmpc2", "dreamerv3", "dreamerv3-2023", "curl")
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
    results.add_argument("--at", type=int, nargs="+", metavar="STEP", help="also tabulate mean +- std return there")
    results.add_argument(
        "--finished-only", action="store_true",
        help="only finished runs of an `sb3-ef benchmark` folder (those with a result.json), not runs in progress",
    )  # fmt: skip
    results.add_argument(
        "--reference", choices=REFERENCE_NAMES,
        help="put the runs beside published DMC curves: DrQ-v2's (frames), TD-MPC2's pixel results (agent steps), "
        "Dreamer-v3's (2024 release: dreamerv3; 2023 paper: dreamerv3-2023) or CURL's from danijar/dreamerv3 (frames)",
    )  # fmt: skip

    model = commands.add_parser("model", help="open-loop prediction, saliency and mask scores of a saved model")
    model.add_argument("path", help="saved model (.zip)")
    model.add_argument(
        "--env", required=True,
        help="env name, e.g. dmc/reacher-easy, metaworld/hammer, toy/agent-v0, or an Atari id: PongNoFrameskip-v4",
    )  # fmt: skip
    model.add_argument("--algo", choices=sorted(EF_ALGORITHMS), help="default: the file's, else each tried in turn")
    model.add_argument("--steps", type=int, help="prediction length T (default: the EF horizon)")
    model.add_argument(
        "--actions", choices=("policy", "figure8"), default="policy",
        help="actions played: the model's, or a figure-eight probe (Box action spaces only)",
    )  # fmt: skip
    model.add_argument("--action-repeat", type=int, default=2, help="action repeat of dmc/ and metaworld/ envs")
    model.add_argument(
        "--env-kwargs", nargs="+", default=None, metavar="KEY:VALUE",
        help="make_env options of the training env, e.g. fast_render:True (default: the run's, if recorded)",
    )  # fmt: skip
    model.add_argument("--seed", type=int, default=0, help="env reset seed")
    model.add_argument("--out", help="output directory (default: next to the model, <name>_analysis)")
    return parser


def parse_env_kwargs(pairs: list[str]) -> dict[str, Any]:
    """``["size:64", "fast_render:True"]`` -> ``{"size": 64, "fast_render": True}`` (literals, else strings)."""
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
    """The env options of the rl-zoo3 run whose folder holds ``model_path`` (``{}`` elsewhere)."""
    from sb3_ef.analysis.zoo_logs import recorded_env_kwargs

    return recorded_env_kwargs(Path(model_path).resolve().parent)


def make_analysis_env(
    name: str,
    frame_shape: tuple[int, ...],
    frame_stack: int,
    action_repeat: int,
    env_kwargs: dict[str, Any] | None = None,
) -> gym.Env:
    """The model's env at its frame size, with the training env's other ``env_kwargs`` (checked against the model);
    an Atari id as :func:`atari_env` makes it."""
    kwargs = dict(env_kwargs or {})
    size = frame_shape[-1]
    for key, expected in (("size", size), ("frame_stack", frame_stack)):
        value = kwargs.pop(key, expected)
        if value != expected:
            raise ValueError(f"env_kwargs {key}={value!r} does not match the model's {key} {expected}")
    if name.startswith(MAKE_ENV_SUITES):
        from sb3_ef.envs import make_env

        return make_env(name, size=size, frame_stack=frame_stack, **{"action_repeat": action_repeat, **kwargs})
    if is_atari(name):
        return atari_env(name, size, frame_stack, **kwargs)
    return gym.make(name, size=size, frame_stack=frame_stack, **kwargs)


def atari_env(name: str, size: int, frame_stack: int, **kwargs: Any) -> gym.Env:
    """An Atari game's observations as SB3's ``make_atari_env`` + ``VecFrameStack`` give them, channels first: the
    ``AtariWrapper``'s grey ``size`` x ``size`` frames, ``frame_stack`` of them, oldest first, zeros before the first;
    for evaluation, a lost life does not end the episode and rewards are not clipped (``kwargs``: ``gym.make``'s)."""
    from stable_baselines3.common.atari_wrappers import AtariWrapper

    env = AtariWrapper(gym.make(name, **kwargs), screen_size=size, terminal_on_life_loss=False, clip_reward=False)
    stacked = gym.wrappers.FrameStackObservation(env, frame_stack, padding_type="zero")
    return gym.wrappers.ReshapeObservation(stacked, (frame_stack, size, size))


def saved_algorithm_classes(path: str, algo: str | None) -> list[type[BaseAlgorithm]]:
    """The classes to load ``path`` with: the one its file records, else ``algo``'s or every EF algorithm in turn."""
    from sb3_ef.common.saved_models import is_legacy, saved_algorithm, saved_data
    from sb3_ef.common.validation import check_model_path

    data = saved_data(check_model_path(path) or path)
    recorded = saved_algorithm(data)
    with_ef = ", ".join(EF_ALGORITHMS.values())
    if recorded is None:
        if data is not None and is_legacy(data):
            raise ValueError(
                f"{path} was saved by sb3-ef 0.1.0: convert it once with `sb3-ef upgrade {path} NEW.zip`, then "
                "analyze NEW.zip"
            )
        return [registry.entry(key).algorithm_class for key in ([algo] if algo else EF_ALGORITHMS)]
    item = registry.by_class_name(recorded)
    if item is None:
        raise ValueError(f"{path} was saved by {recorded}, not by an sb3-ef algorithm: `analyze model` reads {with_ef}")
    if algo is not None and EF_ALGORITHMS[algo] != recorded:
        raise ValueError(
            f"--algo {algo} ({EF_ALGORITHMS[algo]}) does not match {path}, which {recorded} saved: leave --algo out "
            "and the file is loaded as the algorithm it records"
        )
    if not item.ef:
        raise ValueError(
            f"{path} holds a {recorded} model, which has no Ego-Foresight module: `sb3-ef analyze model` shows EF's "
            f"open-loop predictions and saliency, of models of {with_ef}; compare {recorded}'s evaluations with "
            "`sb3-ef analyze results`"
        )
    return [item.algorithm_class]


def load_ef_model(path: str, algo: str | None) -> Any:
    """Load a saved Ego-Foresight model (:func:`saved_algorithm_classes`) with a tiny replay buffer."""
    candidates = saved_algorithm_classes(path, algo)
    if len(candidates) == 1:
        return candidates[0].load(path, buffer_size=ANALYSIS_BUFFER_SIZE, device="auto")
    errors = []
    for algo_class in candidates:
        try:
            return algo_class.load(path, buffer_size=ANALYSIS_BUFFER_SIZE, device="auto")
        except Exception as error:  # report why every candidate failed, not just the last
            errors.append(f"{algo_class.__name__}: {type(error).__name__}: {error}")
    names = " or ".join(algo_class.__name__ for algo_class in candidates)
    raise ValueError(f"Could not load {path} as {names}:\n" + "\n".join(errors))


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
    """Write the prediction image and GIF, ``saliency.png`` and ``scores.json`` of one rollout of a saved model."""
    from sb3_ef.analysis.plots import plot_prediction, plot_saliency
    from sb3_ef.analysis.prediction import figure_eight_actions, save_video
    from sb3_ef.analysis.report import foresight_report, record_rollout

    for name, value in (("steps (--steps)", steps), ("action_repeat (--action-repeat)", action_repeat)):
        if value is not None and (isinstance(value, bool) or not isinstance(value, int) or value < 1):
            raise ValueError(f"{name} must be a positive whole number, got {value!r}")
    if os.path.exists(out) and not os.path.isdir(out):
        raise ValueError(f"The output folder {out!r} is a file: pass a folder (--out)")
    model = load_ef_model(path, algo)
    if getattr(model, "ef", None) is None:
        raise ValueError(f"{path} is a {type(model).__name__} without Ego-Foresight: nothing to analyze")
    if actions == "figure8" and not isinstance(model.action_space, gym.spaces.Box):
        raise ValueError(
            f"--actions figure8 plays a Box's actions (a figure-eight velocity); {path} holds a "
            f"{type(model).__name__} of {model.action_space} actions: analyze it with --actions policy"
        )
    frame_channels = model.frame_shape[0]
    frame_stack = model.observation_space.shape[0] // frame_channels
    if env_kwargs is None:
        env_kwargs = run_env_kwargs(path)
    env = make_analysis_env(env_name, model.frame_shape, frame_stack, action_repeat, env_kwargs)
    if env.observation_space.shape != model.observation_space.shape:
        env.close()
        raise ValueError(
            f"{env_name} gives observations of shape {env.observation_space.shape}, {path} reads "
            f"{model.observation_space.shape} ({frame_stack} frames of {model.frame_shape})"
        )
    steps = steps or model.ef.horizon
    if actions == "figure8":
        sequence = figure_eight_actions(steps, model.action_space.shape[0])
        act = lambda _observation, step: sequence[step]  # noqa: E731
    else:
        actor = EpisodeActor(model)
        act = lambda observation, _step: actor(observation)  # noqa: E731
    try:
        report = foresight_report(model, record_rollout(env, act, steps, seed, frame_channels))
    finally:
        env.close()
    os.makedirs(out, exist_ok=True)
    title = f"{type(model).__name__} on {env_name}, {actions} actions"
    written = {
        "prediction": plot_prediction(report, os.path.join(out, "prediction.png"), title),
        "video": save_video(os.path.join(out, "prediction.gif"), report.predicted, report.rollout.true_frames),
        "saliency": plot_saliency(report, os.path.join(out, "saliency.png"), f"{title}, t+{len(report.predicted)}"),
    }
    scores = {"env": env_name, "env_kwargs": env_kwargs, "steps": len(report.predicted), "actions": actions}
    scores.update(report.scalars())
    written["scores"] = os.path.join(out, "scores.json")
    recorded = {key: None if isinstance(value, float) and np.isnan(value) else value for key, value in scores.items()}
    write_text_atomically(written["scores"], json.dumps(recorded, indent=2))
    print(json.dumps(scores, indent=2))
    print(f"Wrote {', '.join(os.path.basename(path) for path in written.values())} to {out}")
    return written


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``sb3-ef analyze``; returns the exit status."""
    args = build_parser().parse_args(argv)
    if args.command == "results":
        from sb3_ef.analysis.results import analyze_results

        out = args.out or os.path.join(args.directory, "analysis")
        at = tuple(args.at or ())
        analyze_results(args.directory, out, args.return_scale, args.reps, at, args.finished_only, args.reference)
    else:
        out = args.out or os.path.splitext(args.path)[0] + "_analysis"
        env_kwargs = None if args.env_kwargs is None else parse_env_kwargs(args.env_kwargs)
        analyze_model(
            args.path, args.env, out, args.algo, args.steps, args.actions, args.action_repeat, args.seed, env_kwargs
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
