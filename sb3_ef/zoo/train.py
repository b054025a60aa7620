"""``python -m sb3_ef.zoo.train``: rl-zoo3's ``train`` with sb3-ef's algorithms, configs and environments.

Takes exactly rl-zoo3's arguments. Differences, all on top of rl-zoo3's own behaviour:

- ``--algo drqv2_ef | drqv2 | tdmpc2_ef | tdmpc2`` read ``zoo_configs/<algo>.yml`` unless ``--conf-file`` is given;
- ``sb3_ef`` is imported (its gymnasium ids registered) and added to ``--gym-packages`` (recorded in ``args.yml``,
  so subprocess envs and ``enjoy`` find the ids too);
- the whole YAML file and the ``--hyperparams`` overrides are checked before anything is built, so a bad key
  or env id fails at once with the entry and key named;
- ``-optimize`` uses the Optuna samplers of :mod:`sb3_ef.zoo.hyperparams_opt`;
- ``--save-freq`` checkpoints can be resumed, ``-i`` continues a run, and ``--resume RUN_DIR`` continues a run from
  its newest checkpoint with the run's own arguments (:mod:`sb3_ef.zoo.resume`). Options of sb3-ef only:
  ``--resume RUN_DIR``, ``--checkpoint-buffer`` (checkpoints include the replay buffer) and
  ``--keep-checkpoints N`` (default 2).
"""

from __future__ import annotations

import argparse
import functools
import itertools
import json
import os
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
from rl_zoo3 import exp_manager, utils

import sb3_ef  # noqa: F401  (registers the environments)
from sb3_ef.common.checkpoints import latest_checkpoint
from sb3_ef.zoo import config
from sb3_ef.zoo.registration import register_algorithms
from sb3_ef.zoo.resume import ARGV_FILE, CheckpointOptions, ResumingExperimentManager

GYM_PACKAGE = "sb3_ef"


def with_gym_package(argv: list[str]) -> list[str]:
    """Return ``argv`` with ``sb3_ef`` among the ``--gym-packages`` values (added to the user's list, if any)."""
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
    return parser


def _override_values(overrides: list[str]) -> dict[str, Any]:
    """``--hyperparams key:value`` pairs, values evaluated like rl-zoo3 does (in its namespace)."""
    values = {}
    for override in overrides:
        key, _, value = override.partition(":")
        values[key] = eval(value, vars(utils))
    return values


def prepare(argv: Sequence[str]) -> list[str]:
    """Register the algorithms, check the config and return the argv to hand to rl-zoo3."""
    argv = list(argv)
    known, _ = _pre_parser().parse_known_args(argv)
    register_algorithms()  # our keys and config names exist from here on (the overrides may use them)
    if known.algo not in config.ZOO_ALGORITHMS:
        if known.algo not in utils.ALGOS:
            raise ValueError(f"Unknown algorithm {known.algo!r}: expected one of {sorted(utils.ALGOS)}")
        return with_gym_package(argv)
    if known.env not in gym.envs.registry:
        raise ValueError(f"Unknown env id {known.env!r}: sb3-ef registers ids like 'dmc/cheetah-run-v0'")

    conf_file = known.conf_file
    if conf_file is None:
        conf_file = str(config.default_config_path(known.algo))
        argv += ["--conf-file", conf_file]
    algo_class = utils.ALGOS[known.algo]
    overrides = _override_values(known.hyperparams)
    config.check_keys(known.algo, algo_class, overrides, where="--hyperparams")
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
    """The train options sb3-ef adds to rl-zoo3's (removed before rl-zoo3 parses the rest)."""
    parser = argparse.ArgumentParser(add_help=False, allow_abbrev=False)
    parser.add_argument("--resume", default=None, metavar="RUN_DIR")
    parser.add_argument("--checkpoint-buffer", action="store_true")
    parser.add_argument("--keep-checkpoints", type=int, default=2)
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


def resume_argv(run_dir: str, extra: list[str]) -> list[str]:
    """The train arguments that continue ``run_dir``: the run's own (from ``<env>/train_argv.json``) with
    ``-i`` pointing at its newest checkpoint (or its final model), then ``extra`` (later values win)."""
    folder = Path(run_dir)
    saved = sorted(folder.glob(f"*/{ARGV_FILE}"))
    if not folder.is_dir() or len(saved) != 1:
        raise ValueError(
            f"--resume expects an sb3-ef run folder holding <env>/{ARGV_FILE}, got {run_dir!r} "
            f"({'not a folder' if not folder.is_dir() else f'{len(saved)} such files'})"
        )
    checkpoint = latest_checkpoint(folder)
    model_path = checkpoint.model_path if checkpoint is not None else folder / f"{saved[0].parent.name}.zip"
    if not model_path.is_file():
        raise ValueError(f"--resume: {run_dir!r} holds no checkpoint (train with --save-freq) and no final model")
    argv = _without_options(json.loads(saved[0].read_text()), {"-i": True, "--trained-agent": True})
    return [*argv, "-i", str(model_path), *extra]


def _check_trained_agent(argv: list[str]) -> None:
    """Name a ``-i`` value that is not a model zip (rl-zoo3 only asserts it)."""
    for arg, value in itertools.pairwise(argv):
        if arg in ("-i", "--trained-agent") and not (value.endswith(".zip") and os.path.isfile(value)):
            raise ValueError(f"{arg} expects the path of a saved model .zip, got {value!r}")


def run_with_argv(function: Callable[[], None], argv: Sequence[str]) -> None:
    """Call an rl-zoo3 entry point (which parses ``sys.argv``) on ``argv``."""
    saved = sys.argv
    sys.argv = [saved[0], *argv]
    try:
        function()
    finally:
        sys.argv = saved


def main(argv: Sequence[str] | None = None) -> None:
    """Train (or, with ``-optimize``, tune) an agent with rl-zoo3; ``argv`` defaults to the command line."""
    from rl_zoo3 import train as zoo_train

    argv = list(sys.argv[1:] if argv is None else argv)
    options, _ = _sb3_ef_parser().parse_known_args(argv)
    if options.keep_checkpoints < 1:
        raise ValueError(f"--keep-checkpoints must be >= 1, got {options.keep_checkpoints}")
    if options.resume is not None:
        argv = resume_argv(options.resume, _without_options(argv, {"--resume": True}))
    _check_trained_agent(argv)
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
        run_with_argv(zoo_train.train, zoo_argv)
    finally:
        zoo_train.ExperimentManager = saved  # type: ignore[misc]


if __name__ == "__main__":
    main()
