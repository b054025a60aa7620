"""``python -m sb3_ef.zoo.train``: rl-zoo3's ``train`` with sb3-ef's algorithms, configs and environments."""

from __future__ import annotations

import argparse
import functools
import itertools
import os
import sys
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
from rl_zoo3 import exp_manager, hyperparams_opt, utils

import sb3_ef  # noqa: F401  (registers the environments)
from sb3_ef.common.checkpoints import Checkpoint, checkpoint_for, latest_checkpoint
from sb3_ef.common.validation import did_you_mean, is_intact
from sb3_ef.registry import import_target
from sb3_ef.zoo import config
from sb3_ef.zoo.hyperparams_opt import SAMPLERS
from sb3_ef.zoo.options import SB3_EF_TRAIN_OPTIONS, check_train_argv, merge_train_argv, rl_zoo3_parser
from sb3_ef.zoo.registration import register_algorithms
from sb3_ef.zoo.resume import CheckpointOptions, ResumingExperimentManager, recorded_argv

GYM_PACKAGE = "sb3_ef"


def with_gym_package(argv: list[str]) -> list[str]:
    """``argv`` with ``sb3_ef`` among the ``--gym-packages`` (recorded in ``args.yml`` for subprocess envs, enjoy)."""
    if "--gym-packages" in argv:
        index = argv.index("--gym-packages") + 1
        return [*argv[:index], GYM_PACKAGE, *argv[index:]]
    if any(arg.startswith("--gym-packages=") for arg in argv):
        return argv
    return [*argv, "--gym-packages", GYM_PACKAGE]


def _pre_parser() -> argparse.ArgumentParser:
    """The few rl-zoo3 arguments needed to find and check the config (same spellings as rl-zoo3)."""
    parser = argparse.ArgumentParser(add_help=False, allow_abbrev=False)
    parser.add_argument("--algo", default="ppo")
    parser.add_argument("--env", default="CartPole-v1")
    parser.add_argument("-conf", "--conf-file", default=None)
    parser.add_argument("-params", "--hyperparams", nargs="+", default=[])
    parser.add_argument("--env-kwargs", nargs="+", default=[])
    parser.add_argument("--eval-env-kwargs", nargs="+", default=[])
    parser.add_argument("-optimize", "--optimize-hyperparameters", dest="optimize", action="store_true")
    return parser


def override_values(overrides: list[str], option: str = "--hyperparams") -> dict[str, Any]:
    """``key:value`` pairs of ``option``, values evaluated as rl-zoo3 does."""
    values = {}
    for override in overrides:
        key, _, value = override.partition(":")
        try:
            values[key] = eval(value, vars(utils))
        except Exception as error:  # the user's expression: any exception is a mistake in the command line
            hint = ""
            if isinstance(error, NameError) and value.isidentifier():
                hint = f"; values are Python expressions, so a string needs quotes: {key}:\"'{value}'\""
            raise ValueError(
                f"{option} {key}: cannot evaluate {value!r} ({type(error).__name__}: {error}){hint}"
            ) from None
    return values


def prepare(argv: Sequence[str]) -> list[str]:
    """Register the algorithms, check the config and return the argv to hand to rl-zoo3."""
    argv = list(argv)
    known, _ = _pre_parser().parse_known_args(argv)
    register_algorithms()  # our keys and config names exist from here on (the overrides may use them)
    override_values(known.env_kwargs, "--env-kwargs")  # rl-zoo3 would raise the evaluation's error as it is
    override_values(known.eval_env_kwargs, "--eval-env-kwargs")
    if known.algo not in config.ZOO_ALGORITHMS:
        if known.algo not in utils.ALGOS:
            raise ValueError(
                f"Unknown algorithm {known.algo!r}{did_you_mean(known.algo, utils.ALGOS)}: expected one of "
                f"{', '.join(sorted(utils.ALGOS))}"
            )
        return with_gym_package(argv)
    if known.env not in gym.envs.registry:
        raise ValueError(
            f"Unknown env id {known.env!r}{did_you_mean(known.env, gym.envs.registry)}: sb3-ef registers ids like "
            "'dmc/cheetah-run-v0'"
        )

    if known.optimize and known.algo not in hyperparams_opt.HYPERPARAMS_SAMPLER:
        raise ValueError(f"No Optuna sampler for {known.algo!r}: -optimize supports {', '.join(sorted(SAMPLERS))}")
    conf_file = known.conf_file
    if conf_file is None:
        conf_file = str(config.default_config_path(known.algo))
        argv += ["--conf-file", conf_file]
    algo_class = utils.ALGOS[known.algo]
    overrides = override_values(known.hyperparams)
    config.check_keys(known.algo, algo_class, overrides, where="--hyperparams")
    config.check_values(overrides, where="--hyperparams")
    entry = overrides
    if conf_file.endswith((".yml", ".yaml")):
        hyperparams = config.load_config(conf_file)
        config.validate_config(known.algo, algo_class, hyperparams, source=conf_file)
        entry = {**config.select_entry(hyperparams, known.env), **overrides}

    policy_kwargs = entry.get("policy_kwargs") or {}
    if isinstance(policy_kwargs, str):
        policy_kwargs = eval(policy_kwargs, vars(exp_manager))
    register_algorithms(base_policy_kwargs=policy_kwargs)  # samplers merge agent_dim into the entry's kwargs
    return with_gym_package(argv)


def _sb3_ef_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(add_help=False, allow_abbrev=False)
    parser.add_argument("--resume", default=None, metavar="RUN_DIR")
    parser.add_argument("--checkpoint-buffer", action="store_true")
    parser.add_argument("--keep-checkpoints", type=int, default=2)
    return parser


def zoo_help_parser(prog: str = "sb3-ef train") -> argparse.ArgumentParser:
    """``sb3-ef train``'s full parser, for ``--help``: rl-zoo3's own with sb3-ef's options added."""
    from rl_zoo3 import train as zoo_train

    parser = rl_zoo3_parser(zoo_train, "train")
    parser.prog = prog
    parser.description = "Train (or with -optimize, tune) an sb3-ef agent with rl-zoo3."
    group = parser.add_argument_group("sb3-ef options")
    for option in SB3_EF_TRAIN_OPTIONS:
        if option.kind == "flag":
            group.add_argument(*option.names, action="store_true", help=option.help)
        else:
            group.add_argument(*option.names, type=int if option.kind == "int" else str, help=option.help)
    return parser


def _without_options(argv: list[str], options: dict[str, bool]) -> list[str]:
    """``argv`` without the given options (name -> whether it takes a value), in both spellings of a value."""
    kept, skip = [], False
    for arg in argv:
        name = arg.split("=", 1)[0]
        if skip:
            skip = False
        elif name in options:
            skip = options[name] and "=" not in arg
        else:
            kept.append(arg)
    return kept


def resume_point(run_dir: Path, env_folder: str) -> Checkpoint:
    """The newest intact checkpoint or the final model of a run folder, whichever is further (a tie: the checkpoint)."""
    candidates = []
    checkpoint = latest_checkpoint(run_dir, intact=True)
    if checkpoint is not None:
        candidates.append(checkpoint)
    final = run_dir / f"{env_folder}.zip"
    if final.is_file() and is_intact(final):
        candidates.append(checkpoint_for(final))
    elif final.is_file():
        warnings.warn(f"The final model {final} is damaged (not a readable model zip): not resumed from", stacklevel=2)
    if not candidates:
        raise ValueError(
            f"--resume: {str(run_dir)!r} holds no intact checkpoint (train with --save-freq) and no final model"
        )
    return max(candidates, key=lambda candidate: candidate.step)


def resume_argv(run_dir: str, extra: list[str]) -> list[str]:
    """The run's recorded train arguments with ``-i`` at :func:`resume_point` and ``extra`` merged over them."""
    env_folder, recorded = recorded_argv(run_dir)
    model_path = resume_point(Path(run_dir), env_folder.name).model_path
    return merge_train_argv(recorded, ["-i", str(model_path), *extra])


def trained_agent(argv: list[str]) -> str | None:
    """The last ``-i`` model zip of ``argv``, or ``None``; one that is not a readable model zip is refused."""
    trained = None
    for arg, value in itertools.pairwise(argv):
        if arg in ("-i", "--trained-agent"):
            if not (value.endswith(".zip") and os.path.isfile(value)):
                raise ValueError(f"{arg} expects the path of a saved model .zip, got {value!r}")
            if not is_intact(value):
                raise ValueError(f"{arg} {value!r} is damaged (not a readable model zip)")
            trained = value
    return trained


def own_loop_main(argv: list[str], command: str) -> Callable[[list[str]], None] | None:
    """The ``train`` or ``enjoy`` function of ``argv``'s algorithm if it trains in its own loop, else ``None``."""
    options, _ = _sb3_ef_parser().parse_known_args(argv)
    if options.resume is not None:
        try:
            argv = recorded_argv(options.resume)[1]
        except ValueError:  # reported when the run is resumed
            argv = []
    algo = _pre_parser().parse_known_args(argv)[0].algo
    if algo not in config.OWN_LOOPS:
        return None
    return import_target(config.OWN_LOOPS[algo][("train", "enjoy").index(command)])


def run_with_argv(function: Callable[[], None], argv: Sequence[str], prog: str) -> None:
    """Call an rl-zoo3 entry point (which parses ``sys.argv``) on ``argv``; its usage and errors name ``prog``."""
    saved = sys.argv
    sys.argv = [prog, *argv]
    try:
        function()
    finally:
        sys.argv = saved


def main(argv: Sequence[str] | None = None) -> None:
    """Train (or, with ``-optimize``, tune) an agent with rl-zoo3; ``argv`` defaults to the command line."""
    from rl_zoo3 import train as zoo_train

    argv = list(sys.argv[1:] if argv is None else argv)
    if "-h" in argv or "--help" in argv:
        register_algorithms()  # the --algo choices list sb3-ef's algorithms
        zoo_help_parser("sb3-ef optimize" if "-optimize" in argv else "sb3-ef train").print_help()
        return
    check_train_argv(argv)
    own_loop = own_loop_main(argv, "train")
    if own_loop is not None:
        own_loop(argv)
        return
    options, _ = _sb3_ef_parser().parse_known_args(argv)
    if options.resume is not None:
        argv = resume_argv(options.resume, _without_options(argv, {"--resume": True}))
        check_train_argv(argv)  # the run's algorithm and env id
        options, _ = _sb3_ef_parser().parse_known_args(argv)  # the run's recorded sb3-ef options, and the new ones
    trained = trained_agent(argv)
    if trained is not None and not options.checkpoint_buffer and checkpoint_for(trained).replay_buffer_path:
        # New checkpoints without the buffer would replace (and prune) the ones that hold it.
        print(f"{trained} has a replay buffer beside it: the run's checkpoints include it (--checkpoint-buffer)")
        argv, options.checkpoint_buffer = [*argv, "--checkpoint-buffer"], True  # recorded for --resume
    zoo_argv = prepare(_without_options(argv, {"--checkpoint-buffer": False, "--keep-checkpoints": True}))
    manager = functools.partial(
        ResumingExperimentManager,
        checkpoint_options=CheckpointOptions(options.checkpoint_buffer, options.keep_checkpoints),
        argv=argv,
    )
    saved = zoo_train.ExperimentManager
    # rl-zoo3's train builds its manager by this module-level name: swapped in for the run (mypy reads it as a class).
    zoo_train.ExperimentManager = manager  # type: ignore[misc, assignment]
    try:
        run_with_argv(zoo_train.train, zoo_argv, "sb3-ef optimize" if "-optimize" in argv else "sb3-ef train")
    finally:
        zoo_train.ExperimentManager = saved  # type: ignore[misc]


if __name__ == "__main__":
    main()
