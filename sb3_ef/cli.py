"""The ``sb3-ef`` console script: each subcommand's command line checked before its heavy imports (docs/zoo.md)."""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Sequence
from typing import NamedTuple

from sb3_ef.common.interrupt import INTERRUPTED_STATUS, interrupted_line
from sb3_ef.envs.backend import RenderingBackendError
from sb3_ef.registry import import_target

#: Exceptions that report a mistake in the command line or the installation, not a bug.
USER_ERRORS = (ValueError, OSError, ImportError, RenderingBackendError)


class Command(NamedTuple):
    """A subcommand: its ``module:function`` main, help line, arguments put first, and a light ``check(argv)``."""

    target: str
    help: str
    prefix: tuple[str, ...] = ()
    check: str | None = None

    def __call__(self, argv: list[str]) -> int | None:
        argv = [*self.prefix, *argv]
        if self.check is not None and not {"-h", "--help"} & set(argv):
            import_target(self.check)(argv)
        return import_target(self.target)(argv)


_TRAIN_CHECK = "sb3_ef.zoo.options:check_train_argv"
COMMANDS: dict[str, Command] = {
    "train": Command("sb3_ef.zoo.train:main", "train an agent from a zoo config (rl-zoo3 train arguments)",
                     check=_TRAIN_CHECK),
    "enjoy": Command("sb3_ef.zoo.enjoy:main", "run a trained agent (rl-zoo3 enjoy arguments)",
                     check="sb3_ef.zoo.options:check_enjoy_argv"),
    "optimize": Command("sb3_ef.zoo.train:main",
                        "tune hyperparameters with Optuna (rl-zoo3 train arguments, -optimize implied)",
                        prefix=("-optimize",), check=_TRAIN_CHECK),
    "analyze": Command("sb3_ef.analysis.cli:main", "predictions, saliency, ENS and rliable plots (sb3_ef.analysis)"),
    "benchmark": Command("sb3_ef.grid.cli:main", "train a grid of runs locally or on a Ray cluster (sb3_ef.grid)"),
    "collect": Command("sb3_ef.offline.cli:collect_main",
                       "record babbling or policy episodes (frames, actions, agent masks) (sb3_ef.offline)"),
    "pretrain": Command("sb3_ef.offline.cli:pretrain_main",
                        "train an encoder + Ego-Foresight offline on episodes (sb3_ef.offline)"),
    "predict": Command("sb3_ef.offline.cli:predict_main",
                       "open-loop predictions of a pretrained model as PNG and GIF/MP4 (sb3_ef.offline)"),
    "upgrade": Command("sb3_ef.upgrade:main", "convert a model file saved by sb3-ef 0.1.0 to this version's format"),
}  # fmt: skip


def _parser() -> argparse.ArgumentParser:
    from sb3_ef import __version__

    parser = argparse.ArgumentParser(
        prog="sb3-ef",
        description="Ego-Foresight for Stable-Baselines3: training, analysis, benchmark grids and offline EF.",
    )
    parser.add_argument("--version", action="version", version=f"sb3-ef {__version__}")
    subparsers = parser.add_subparsers(dest="command", required=True, metavar="{" + ",".join(COMMANDS) + "}")
    for name, command in COMMANDS.items():
        subparsers.add_parser(name, help=command.help, add_help=False)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Dispatch ``sb3-ef <command> ...``; ``argv`` defaults to the command line. Returns the exit status."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] not in COMMANDS:
        _parser().parse_args(argv)  # prints help or the version, or exits with an error naming the valid commands
        return 0
    try:
        return COMMANDS[argv[0]](argv[1:]) or 0
    except USER_ERRORS as error:
        if os.environ.get("SB3_EF_TRACEBACK") == "1":
            raise
        notes = getattr(error, "__notes__", ())  # e.g. the checkpoint a failed run continues from
        message = " ".join(" ".join([str(error), *notes]).split()) or type(error).__name__
        print(f"sb3-ef {argv[0]}: error: {message}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as interrupt:
        if os.environ.get("SB3_EF_TRACEBACK") == "1":
            raise
        print(f"\n{interrupted_line(f'sb3-ef {argv[0]}', interrupt)}", file=sys.stderr, flush=True)
        return INTERRUPTED_STATUS


if __name__ == "__main__":
    sys.exit(main())
