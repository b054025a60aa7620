"""The ``sb3-ef`` console script: ``train``, ``enjoy``, ``optimize`` (rl-zoo3) and ``analyze`` (sb3_ef.analysis).

Each subcommand forwards the rest of the command line untouched, so ``sb3-ef train --help`` shows rl-zoo3's
training options and ``sb3-ef analyze --help`` the analysis ones.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence


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


def _collect(argv: list[str]) -> int:
    from sb3_ef.offline.cli import collect_main

    return collect_main(argv)


def _pretrain(argv: list[str]) -> int:
    from sb3_ef.offline.cli import pretrain_main

    return pretrain_main(argv)


def _predict(argv: list[str]) -> int:
    from sb3_ef.offline.cli import predict_main

    return predict_main(argv)


COMMANDS: dict[str, tuple[Callable[[list[str]], int | None], str]] = {
    "train": (_train, "train an agent from a zoo config (rl-zoo3 train arguments)"),
    "enjoy": (_enjoy, "run a trained agent (rl-zoo3 enjoy arguments)"),
    "optimize": (_optimize, "tune hyperparameters with Optuna (rl-zoo3 train arguments, -optimize implied)"),
    "analyze": (_analyze, "predictions, saliency, ENS and rliable plots (sb3_ef.analysis)"),
    "collect": (_collect, "record babbling or policy episodes (frames, actions, agent masks) (sb3_ef.offline)"),
    "pretrain": (_pretrain, "train an encoder + Ego-Foresight offline on episodes (sb3_ef.offline)"),
    "predict": (_predict, "open-loop predictions of a pretrained model as PNG and GIF/MP4 (sb3_ef.offline)"),
}


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="sb3-ef", description="Ego-Foresight for Stable-Baselines3: rl-zoo3 training and analysis."
    )
    subparsers = parser.add_subparsers(dest="command", required=True, metavar="{" + ",".join(COMMANDS) + "}")
    for name, (_, help_text) in COMMANDS.items():
        subparsers.add_parser(name, help=help_text, add_help=False)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Dispatch ``sb3-ef <command> ...``; ``argv`` defaults to the command line. Returns the exit status."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] in COMMANDS:
        return COMMANDS[argv[0]][0](argv[1:]) or 0
    _parser().parse_args(argv)  # prints help, or exits with an error naming the valid commands
    return 0


if __name__ == "__main__":
    sys.exit(main())
