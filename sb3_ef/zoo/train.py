"""``python -m sb3_ef.zoo.train``: rl-zoo3's ``train`` with sb3-ef's algorithms, configs and environments.

Takes exactly rl-zoo3's arguments. Differences, all on top of rl-zoo3's own behaviour:

- ``--algo drqv2_ef | drqv2 | tdmpc2_ef | tdmpc2`` read ``zoo_configs/<algo>.yml`` unless ``--conf-file`` is given;
- ``sb3_ef`` is imported (its gymnasium ids registered) and added to ``--gym-packages`` (recorded in ``args.yml``,
  so subprocess envs and ``enjoy`` find the ids too);
- the whole YAML file and the ``--hyperparams`` overrides are checked before anything is built, so a bad key
  or env id fails at once with the entry and key named;
- ``-optimize`` uses the Optuna samplers of :mod:`sb3_ef.zoo.hyperparams_opt`.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence
from typing import Any

import gymnasium as gym
from rl_zoo3 import exp_manager, utils

import sb3_ef  # noqa: F401  (registers the environments)
from sb3_ef.zoo import config
from sb3_ef.zoo.registration import register_algorithms

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
    from rl_zoo3.train import train

    run_with_argv(train, prepare(sys.argv[1:] if argv is None else argv))


if __name__ == "__main__":
    main()
