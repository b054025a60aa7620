"""The command-line options of ``sb3-ef train``, ``optimize`` and ``enjoy``, checked before heavy imports."""

from __future__ import annotations

import argparse
import ast
import importlib
import types
from collections.abc import Sequence
from typing import Any, NamedTuple

from sb3_ef.common.validation import did_you_mean


class Option(NamedTuple):
    """One option: its spellings, ``kind`` (``flag``, ``int``, ``str``, ``list``, ``pairs``), choices, help."""

    names: tuple[str, ...]
    kind: str = "str"
    choices: tuple[str, ...] | None = None
    help: str | None = None


_COMMON = (
    Option(("--gym-packages",), "list"),
    Option(("--env-kwargs",), "pairs"),
    Option(("--num-threads",), "int"),
    Option(("--verbose",), "int"),
    Option(("--device",)),
    Option(("--seed",), "int"),
    Option(("-P", "--progress"), "flag"),
)

#: rl-zoo3's ``train`` options (``--algo`` choices are checked later, against the registered algorithms).
TRAIN_OPTIONS: tuple[Option, ...] = (
    *_COMMON,
    Option(("--algo",)),
    Option(("--env",)),
    Option(("-tb", "--tensorboard-log")),
    Option(("-i", "--trained-agent")),
    Option(("--truncate-last-trajectory",)),
    Option(("-n", "--n-timesteps"), "int"),
    Option(("--log-interval",), "int"),
    Option(("--eval-freq",), "int"),
    Option(("--optimization-log-path",)),
    Option(("--eval-episodes",), "int"),
    Option(("--n-eval-envs",), "int"),
    Option(("--save-freq",), "int"),
    Option(("--save-replay-buffer",), "flag"),
    Option(("-f", "--log-folder")),
    Option(("--vec-env",), choices=("dummy", "subproc")),
    Option(("--n-trials",), "int"),
    Option(("--max-total-trials",), "int"),
    Option(("-optimize", "--optimize-hyperparameters"), "flag"),
    Option(("--no-optim-plots",), "flag"),
    Option(("--n-jobs",), "int"),
    Option(("--sampler",), choices=("random", "tpe", "auto")),
    Option(("--pruner",), choices=("halving", "median", "none")),
    Option(("--n-startup-trials",), "int"),
    Option(("--n-evaluations",), "int"),
    Option(("--storage",)),
    Option(("--study-name",)),
    Option(("--trial-id",), "int"),
    Option(("--eval-env-kwargs",), "pairs"),
    Option(("-params", "--hyperparams"), "pairs"),
    Option(("-conf", "--conf-file")),
    Option(("-uuid", "--uuid"), "flag"),
    Option(("--track",), "flag"),
    Option(("--wandb-project-name",)),
    Option(("--wandb-entity",)),
    Option(("--wandb-group",)),
    Option(("-tags", "--wandb-tags"), "list"),
)

#: The algorithm keys rl-zoo3 itself registers (``rl_zoo3.utils.ALGOS``; a test compares them with rl-zoo3's).
RL_ZOO3_ALGORITHMS = ("a2c", "ddpg", "dqn", "ppo", "sac", "td3", "ars", "crossq", "qrdqn", "tqc", "trpo", "ppo_lstm")

#: The ``train`` options sb3-ef adds (removed before rl-zoo3 parses the rest).
SB3_EF_TRAIN_OPTIONS: tuple[Option, ...] = (
    Option(
        ("--resume",),
        help="RUN_DIR: continue an sb3-ef run folder (logs/<algo>/<env>_<n>) from its newest intact checkpoint or its "
        "final model, whichever is further, with the run's own arguments (later arguments win)",
    ),
    Option(("--checkpoint-buffer",), "flag", help="--save-freq checkpoints include the replay buffer"),
    Option(("--keep-checkpoints",), "int", help="how many of the newest --save-freq checkpoints are kept (default 2)"),
)

ENJOY_OPTIONS: tuple[Option, ...] = (
    *_COMMON,
    Option(("--env",)),
    Option(("-f", "--folder")),
    Option(("--algo",)),
    Option(("-n", "--n-timesteps"), "int"),
    Option(("--n-envs",), "int"),
    Option(("--exp-id",), "int"),
    Option(("--no-render",), "flag"),
    Option(("--deterministic",), "flag"),
    Option(("--load-best",), "flag"),
    Option(("--load-checkpoint",), "int"),
    Option(("--load-last-checkpoint",), "flag"),
    Option(("--stochastic",), "flag"),
    Option(("--norm-reward",), "flag"),
    Option(("--reward-log",)),
    Option(("--custom-objects",), "flag"),
)

#: Options whose value, when given, must be >= 1 (``-1`` allowed where listed: rl-zoo3's "default").
POSITIVE = {
    "n_timesteps": False,
    "eval_episodes": False,
    "n_eval_envs": False,
    "n_envs": False,
    "log_interval": True,
    "eval_freq": True,
    "save_freq": True,
    "keep_checkpoints": False,
    "n_trials": False,
    "n_jobs": False,
}


class UsageError(ValueError):
    """A mistake in the command line (reported as one line, exit status 2)."""


class _Parser(argparse.ArgumentParser):
    def error(self, message: str):
        raise UsageError(message)


def _pair(option: str):
    """The ``type`` of one ``key:value`` item: checks the form and that the value parses as Python."""

    def parse(item: str) -> str:
        key, separator, value = item.partition(":")
        if not separator or not key:
            raise argparse.ArgumentTypeError(f"expected key:value items (e.g. batch_size:32), got {item!r}")
        try:
            compile(value, f"{option} {key}", "eval")
        except SyntaxError as error:
            raise argparse.ArgumentTypeError(f"{key}: {value!r} is not a Python expression ({error.msg})") from None
        return item

    return parse


def build_parser(options: Sequence[Option], prog: str) -> argparse.ArgumentParser:
    """A parser of ``options`` that raises :class:`UsageError` (values unevaluated, defaults ``None``)."""
    parser = _Parser(prog=prog, add_help=False)  # abbreviations allowed, as rl-zoo3's parsers allow them
    for option in options:
        if option.kind == "flag":
            parser.add_argument(*option.names, action="store_true", default=None)
        else:
            parser.add_argument(
                *option.names,
                type={"int": int, "pairs": _pair(option.names[-1])}.get(option.kind, str),
                nargs="+" if option.kind in ("list", "pairs") else None,
                choices=option.choices,
            )
    return parser


def check_zoo_argv(argv: Sequence[str], options: Sequence[Option], prog: str) -> argparse.Namespace:
    """Parse ``argv`` against ``options`` and check the :data:`POSITIVE` counts; raise :class:`UsageError`."""
    parser = build_parser(options, prog)
    args, unknown = parser.parse_known_args(list(argv))
    if unknown:
        known = [name for option in options for name in option.names if name.startswith("--")]
        first = unknown[0]
        raise UsageError(
            f"unrecognized arguments: {' '.join(unknown)}{did_you_mean(first.split('=')[0], known, cutoff=0.75)}"
        )
    for dest, minus_one in POSITIVE.items():
        value = getattr(args, dest, None)
        if value is not None and value < 1 and not (minus_one and value == -1):
            flag = "--" + dest.replace("_", "-")
            raise UsageError(f"{flag} must be >= 1{' (or -1)' if minus_one else ''}, got {value}")
    return args


def check_algo_and_env(args: argparse.Namespace) -> None:
    """Raise :class:`UsageError` for an ``--algo`` or ``--env`` that is not registered (after ``--gym-packages``)."""
    from sb3_ef import registry

    algorithms = (*registry.ALGORITHMS, *RL_ZOO3_ALGORITHMS)
    algo = args.algo or "ppo"
    if algo not in algorithms:
        raise UsageError(
            f"Unknown algorithm {algo!r}{did_you_mean(algo, algorithms)}: expected one of "
            f"{', '.join(sorted(algorithms))}"
        )
    import gymnasium as gym

    import sb3_ef  # noqa: F401  (registers sb3-ef's env ids)
    from sb3_ef.envs.registration import register_atari

    for package in args.gym_packages or ():
        try:
            importlib.import_module(package)  # as rl-zoo3 does before it looks the id up
        except ImportError as error:
            raise UsageError(f"--gym-packages: cannot import {package!r} ({error})") from None
    env = args.env or "CartPole-v1"
    register_atari(env)
    if env not in gym.envs.registry:
        raise UsageError(
            f"Unknown env id {env!r}{did_you_mean(env, gym.envs.registry)}: sb3-ef registers ids like "
            "'dmc/cheetah-run-v0' (other packages' ids: import them with --gym-packages)"
        )


def check_n_envs(pairs: Sequence[str] | None) -> None:
    """Raise :class:`UsageError` for an ``n_envs`` in ``--hyperparams`` that is not a positive integer (rl-zoo3 and SB3
    would divide by it and fail deep in their set-up); an expression that is not a literal is left to rl-zoo3."""
    for item in pairs or ():
        key, _, value = item.partition(":")
        if key.strip() != "n_envs":
            continue
        try:
            n_envs = ast.literal_eval(value.strip())
        except (ValueError, SyntaxError):
            continue
        if isinstance(n_envs, bool) or not isinstance(n_envs, int) or n_envs < 1:
            raise UsageError(
                f"--hyperparams n_envs must be a positive integer (the number of envs stepped together), got {value}"
            )


def check_train_argv(argv: Sequence[str]) -> argparse.Namespace:
    """Check the arguments of ``sb3-ef train`` / ``optimize`` (with ``--resume``, algo and env are checked later)."""
    args = check_zoo_argv(argv, (*TRAIN_OPTIONS, *SB3_EF_TRAIN_OPTIONS), "sb3-ef train")
    check_n_envs(args.hyperparams)
    if args.resume is None:
        check_algo_and_env(args)
        options = {"--checkpoint-buffer": args.checkpoint_buffer, "--keep-checkpoints": args.keep_checkpoints}
        given = [flag for flag, value in options.items() if value is not None]
        if given and (args.save_freq is None or args.save_freq < 1):
            raise UsageError(f"{' and '.join(given)}: options of the --save-freq checkpoints, give --save-freq N too")
    return args


def check_enjoy_argv(argv: Sequence[str]) -> argparse.Namespace:
    """Check the arguments of ``sb3-ef enjoy``."""
    args = check_zoo_argv(argv, ENJOY_OPTIONS, "sb3-ef enjoy")
    check_algo_and_env(args)
    return args


def _dest(option: Option) -> str:
    return next(name for name in option.names if name.startswith("--"))[2:].replace("-", "_")


def _as_argv(args: argparse.Namespace, options: Sequence[Option]) -> list[str]:
    """The command line that parses to ``args`` (a namespace of :func:`build_parser`; ``None``: not given)."""
    argv: list[str] = []
    for option in options:
        value = getattr(args, _dest(option))
        if value is None:
            continue
        name = option.names[0]  # rl-zoo3's own spelling (-i, -n, -f, -params)
        if option.kind == "flag":
            argv.append(name)
        else:
            argv += [name, *(value if isinstance(value, list) else [str(value)])]
    return argv


def _merged_pairs(recorded: list[str] | None, given: list[str]) -> list[str]:
    """``key:value`` items of ``recorded`` with those of ``given`` over them, key by key."""
    pairs = {item.partition(":")[0]: item for item in recorded or ()}
    pairs.update({item.partition(":")[0]: item for item in given})
    return list(pairs.values())


def merge_train_argv(recorded: Sequence[str], given: Sequence[str]) -> list[str]:
    """``recorded`` train arguments with ``given``'s over them, ``key:value`` lists merged key by key."""
    options = (*TRAIN_OPTIONS, *SB3_EF_TRAIN_OPTIONS)
    parser = build_parser(options, "sb3-ef train --resume")
    merged, given_args = parser.parse_args(list(recorded)), parser.parse_args(list(given))
    for option in options:
        dest = _dest(option)
        value = getattr(given_args, dest)
        if value is not None:
            setattr(merged, dest, _merged_pairs(getattr(merged, dest), value) if option.kind == "pairs" else value)
    return _as_argv(merged, options)


class _ParserBuilt(Exception):
    """Carries the parser an rl-zoo3 entry point built, instead of letting it parse."""


def rl_zoo3_parser(module: types.ModuleType, function: str) -> argparse.ArgumentParser:
    """The parser rl-zoo3's ``module.function()`` (``train`` or ``enjoy``) builds, taken when it would parse."""

    class Capture(argparse.ArgumentParser):
        def parse_args(self, *args: Any, **kwargs: Any) -> Any:
            raise _ParserBuilt(self)

    saved = module.argparse
    module.argparse = types.SimpleNamespace(ArgumentParser=Capture)  # type: ignore[attr-defined]
    try:
        getattr(module, function)()
    except _ParserBuilt as built:
        return built.args[0]
    finally:
        module.argparse = saved  # type: ignore[attr-defined]
    raise RuntimeError(f"{module.__name__}.{function}() returned without parsing arguments")
