"""The ``sb3-ef`` console script: ``train``, ``enjoy``, ``optimize`` (rl-zoo3) and ``analyze`` (sb3_ef.analysis).

Each subcommand forwards the rest of the command line untouched, so ``sb3-ef train --help`` shows rl-zoo3's
training options and ``sb3-ef analyze --help`` the analysis ones. A user error (bad argument, missing file, missing
package or rendering backend) is printed as one line, ``sb3-ef: error: ...``, with exit status 2; set
``SB3_EF_TRACEBACK=1`` to see the traceback instead.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Callable, Sequence

from sb3_ef.envs.backend import RenderingBackendError

#: Exceptions that report a mistake in the command line or the installation, not a bug.
USER_ERRORS = (ValueError, OSError, ImportError, RenderingBackendError)


def _train(argv: list[str]) -> None:
    from sb3_ef.zoo.train import main

    main(argv)


def _optimize(argv: list[str]) -> None:
    from sb3_ef.zoo.train import main

    main(["-optimize", *argv])


def _enjoy(argv: list[str]) -> None:
    from sb3_ef.zoo.enjoy import main

    main(argv)


def _analyze(argv: list[str]) -> int:
    from sb3_ef.analysis.cli import main

    return main(argv)


def _benchmark(argv: list[str]) -> int:
    from sb3_ef.benchmark.cli import main

    return main(argv)


COMMANDS: dict[str, tuple[Callable[[list[str]], int | None], str]] = {
    "train": (_train, "train an agent from a zoo config (rl-zoo3 train arguments)"),
    "enjoy": (_enjoy, "run a trained agent (rl-zoo3 enjoy arguments)"),
    "optimize": (_optimize, "tune hyperparameters with Optuna (rl-zoo3 train arguments, -optimize implied)"),
    "analyze": (_analyze, "predictions, saliency, ENS and rliable plots (sb3_ef.analysis)"),
    "benchmark": (_benchmark, "train a grid of runs locally or on a Ray cluster (sb3_ef.benchmark)"),
}


def _parser() -> argparse.ArgumentParser:
    from sb3_ef import __version__

    parser = argparse.ArgumentParser(
        prog="sb3-ef", description="Ego-Foresight for Stable-Baselines3: rl-zoo3 training and analysis."
    )
    parser.add_argument("--version", action="version", version=f"sb3-ef {__version__}")
    subparsers = parser.add_subparsers(dest="command", required=True, metavar="{" + ",".join(COMMANDS) + "}")
    for name, (_, help_text) in COMMANDS.items():
        subparsers.add_parser(name, help=help_text, add_help=False)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Dispatch ``sb3-ef <command> ...``; ``argv`` defaults to the command line. Returns the exit status."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] not in COMMANDS:
        _parser().parse_args(argv)  # prints help or the version, or exits with an error naming the valid commands
        return 0
    try:
        return COMMANDS[argv[0]][0](argv[1:]) or 0
    except USER_ERRORS as error:
        if os.environ.get("SB3_EF_TRACEBACK") == "1":
            raise
        message = " ".join(str(error).split()) or type(error).__name__
        print(f"sb3-ef {argv[0]}: error: {message}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
