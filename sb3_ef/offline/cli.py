"""``sb3-ef collect``, ``pretrain`` and ``predict``: offline Ego-Foresight from the command line (docs/offline.md)."""

from __future__ import annotations

import argparse
import json
import os
from collections.abc import Callable
from typing import Any, TypeVar

from sb3_ef import registry
from sb3_ef.common.validation import PRECISIONS

N = TypeVar("N", int, float)


def _number_type(cast: Callable[[str], N], accepts: Callable[[N], bool], expected: str) -> Callable[[str], N]:
    """An argparse type: ``cast`` of the text, refused with "expected <expected>" unless ``accepts`` it."""

    def parse(text: str) -> N:
        try:
            value = cast(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}") from None
        if not accepts(value):
            raise argparse.ArgumentTypeError(f"expected {expected}, got {value}")
        return value

    return parse


positive_int = _number_type(int, lambda value: value >= 1, "a positive integer")
non_negative_int = _number_type(int, lambda value: value >= 0, "an integer >= 0")
positive_float = _number_type(float, lambda value: value > 0, "a positive number")
holdout_value = _number_type(
    float, lambda value: 0 <= value < 1 or (value.is_integer() and value >= 1), "a count of episodes or a fraction < 1"
)


def json_object(text: str) -> dict[str, Any]:
    """argparse type: a JSON object such as ``{"width": 32}``, of finite numbers (no ``Infinity`` or ``NaN``)."""

    def refuse(constant: str) -> None:
        raise argparse.ArgumentTypeError(f"expected finite numbers, got {constant} in {text!r}")

    try:
        value = json.loads(text, parse_constant=refuse)
    except json.JSONDecodeError as error:
        raise argparse.ArgumentTypeError(
            f"expected a JSON object such as '{{\"decoder_channels\": 32}}' (keys and strings in double quotes), "
            f"got {text!r}: {error.msg} at character {error.pos + 1}"
        ) from None
    if not isinstance(value, dict):
        raise argparse.ArgumentTypeError(f"expected a JSON object ({{...}}), got {type(value).__name__} {text!r}")
    return value


def collect_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="sb3-ef collect", description="record episodes (frames, actions, masks)")
    parser.add_argument("env", help="env name, e.g. metaworld/hammer, dmc/reacher-easy, toy/agent-v0")
    parser.add_argument("out", help="output folder: one .npz / .h5 file per episode, or a LeRobot dataset")
    parser.add_argument("--episodes", type=positive_int, default=10)
    parser.add_argument("--size", type=positive_int, default=64, help="frame size (ignored with --policy: the model's)")
    parser.add_argument("--action-repeat", type=positive_int, default=2)
    parser.add_argument("--mode", choices=("sign", "clamped_uniform"), default="sign", help="babbling actions")
    parser.add_argument("--policy", help="saved DrQv2EF / TDMPC2EF (.zip) acting instead of babbling")
    parser.add_argument("--algo", choices=registry.keys(warm_start=True), help="algorithm of --policy")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--slow-render", action="store_true", help="render shadows and reflections (slower)")
    parser.add_argument("--no-masks", action="store_true", help="skip the agent masks (one render less per step)")
    parser.add_argument(
        "--format", choices=("npz", "h5", "lerobot"), default="npz", help="lerobot: a LeRobot v3.0 dataset (AV1 video)"
    )
    parser.add_argument("--no-progress", action="store_true")
    return parser


def collect_main(argv: list[str] | None = None) -> int:
    args = collect_parser().parse_args(argv)
    from sb3_ef.offline.collect import collect

    names = ("episodes", "size", "action_repeat", "mode", "policy", "algo", "seed")
    paths = collect(
        args.env, args.out, fast_render=not args.slow_render, masks=not args.no_masks, file_format=args.format,
        progress_bar=not args.no_progress, **{name: getattr(args, name) for name in names},
    )  # fmt: skip
    if args.format == "lerobot":
        with open(os.path.join(args.out, "meta", "info.json")) as file:
            count = json.load(file)["total_episodes"]
        print(f"{count} episodes in {args.out} (a LeRobot v3.0 dataset)")
    else:
        print(f"{len(paths)} episodes in {args.out} ({os.path.basename(paths[0])} .. {os.path.basename(paths[-1])})")
    return 0


def pretrain_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="sb3-ef pretrain", description="train encoder + Ego-Foresight offline")
    parser.add_argument(
        "dataset",
        help="episode folder (.npz/.h5), LeRobot dataset folder, RLDS/TFDS folder (or rlds:PATH), .tfrecord file or "
        "folder (BAIR), or minari:<id>",
    )
    parser.add_argument("out", help="output folder: checkpoint.pt, model.pt, metrics.json, tb/")
    parser.add_argument("--encoder", choices=("dcgan-unet", "drqv2", "tdmpc2"), default="dcgan-unet")
    parser.add_argument("--context", type=positive_int, default=3, help="stacked context frames (the RL frame stack)")
    parser.add_argument("--horizon", type=positive_int, default=10, help="largest prediction step k")
    parser.add_argument("--agent-dim", type=positive_int, default=32)
    parser.add_argument("--steps", type=positive_int, default=10_000, help="updates in all (a resumed run included)")
    parser.add_argument("--batch-size", type=positive_int, default=32)
    parser.add_argument("--lr", type=positive_float, default=1e-3)
    parser.add_argument(
        "--shift-pad", type=non_negative_int, default=0, help="random-shift augmentation in pixels (0: none)"
    )
    parser.add_argument(
        "--holdout", type=holdout_value, default=0.1, help="held-out episodes: a count, or a fraction < 1"
    )
    parser.add_argument("--eval-every", type=positive_int, default=1000)
    parser.add_argument("--checkpoint-every", type=positive_int, default=500)
    parser.add_argument("--encoder-kwargs", type=json_object, default={}, help="JSON, e.g. '{\"width\": 32}'")
    parser.add_argument("--ef-kwargs", type=json_object, default={}, help="JSON, e.g. '{\"decoder_channels\": 32}'")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--device", default="cpu")
    parser.add_argument(
        "--precision", choices=PRECISIONS, default="fp32", help="bf16: bfloat16 mixed precision (docs/precision.md)"
    )
    parser.add_argument(
        "--threads", type=positive_int, help="torch CPU threads (1 is fastest on a busy shared machine)"
    )
    parser.add_argument("--no-resume", action="store_true", help="start over even if OUT/checkpoint.pt exists")
    parser.add_argument("--overwrite", action="store_true", help="train again over a finished run in OUT")
    parser.add_argument(
        "--cache-mb", type=positive_float, default=1024, help="memory for decoded training episodes; more is streamed"
    )
    parser.add_argument(
        "--workers", type=non_negative_int, default=0, help="DataLoader processes decoding training windows"
    )
    add_reader_arguments(parser)
    parser.add_argument("--no-progress", action="store_true")
    return parser


def add_reader_arguments(parser: argparse.ArgumentParser) -> None:
    """Camera / image and action selection for LeRobot and RLDS datasets."""
    group = parser.add_argument_group("LeRobot and RLDS datasets")
    group.add_argument("--camera", help="LeRobot camera feature, e.g. observation.images.top (default: the first)")
    group.add_argument("--action-key", help="LeRobot action feature (default: action)")
    group.add_argument("--image-key", help="RLDS image feature without steps/, e.g. observation/image")
    group.add_argument("--action-keys", nargs="+", help="RLDS action features without steps/, concatenated")
    group.add_argument("--layout", help="RLDS Open X-Embodiment layout name (default: from the folder name)")
    group.add_argument("--image-size", type=positive_int, help="resize LeRobot / RLDS frames to N x N")


def reader_options(args: argparse.Namespace) -> dict[str, Any]:
    """The reader options given on the command line (only those set), checked against the dataset kind."""
    from sb3_ef.offline.lerobot import is_lerobot_dataset
    from sb3_ef.offline.readers import RLDS_PREFIX
    from sb3_ef.offline.rlds import is_rlds_folder

    names = ("camera", "action_key", "image_key", "action_keys", "layout", "image_size")
    options = {name: getattr(args, name) for name in names if getattr(args, name) is not None}
    lerobot, rlds = {"camera", "action_key"}, {"image_key", "action_keys", "layout"}
    if is_lerobot_dataset(args.dataset):
        kind, allowed = "a LeRobot dataset", lerobot | {"image_size"}
    elif args.dataset.startswith(RLDS_PREFIX) or is_rlds_folder(args.dataset):
        kind, allowed = "an RLDS folder", rlds | {"image_size"}
    else:
        kind, allowed = "neither a LeRobot dataset nor an RLDS folder", set()
    for name in sorted(set(options) - allowed):
        where = "LeRobot datasets" if name in lerobot else "RLDS folders" if name in rlds else "LeRobot and RLDS data"
        raise ValueError(f"--{name.replace('_', '-')} applies to {where} only; {args.dataset} is {kind}")
    return options


def pretrain_main(argv: list[str] | None = None) -> int:
    args = pretrain_parser().parse_args(argv)
    from sb3_ef.offline.pretrain import pretrain
    from sb3_ef.offline.readers import open_dataset

    if args.threads:
        import torch

        torch.set_num_threads(args.threads)
    holdout = args.holdout if args.holdout < 1 else int(args.holdout)
    options = reader_options(args)
    dataset = open_dataset(args.dataset, args.context + args.horizon, **options) if options else args.dataset
    names = "encoder context horizon agent_dim steps batch_size shift_pad eval_every checkpoint_every encoder_kwargs"
    names += " ef_kwargs seed device precision overwrite"
    kwargs = {name: getattr(args, name) for name in names.split()}
    _, scores = pretrain(
        dataset, args.out, learning_rate=args.lr, holdout=holdout, resume=not args.no_resume,
        progress_bar=not args.no_progress, cache_mb=args.cache_mb, workers=args.workers, **kwargs,
    )  # fmt: skip
    print(json.dumps({key: value for key, value in scores.items() if not isinstance(value, list)}, indent=2))
    return 0


def predict_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="sb3-ef predict", description="open-loop predictions of a pretrained model")
    parser.add_argument("model", help="model.pt or checkpoint.pt written by sb3-ef pretrain")
    parser.add_argument("out", help="output folder: prediction.png and prediction.gif / .mp4")
    parser.add_argument("--dataset", required=True, help="where the context frames come from (as for pretrain)")
    parser.add_argument("--episode", type=non_negative_int, default=0)
    parser.add_argument("--start", type=non_negative_int, help="last context frame (default: context - 1)")
    parser.add_argument("--actions", choices=("dataset", "figure8"), default="dataset")
    parser.add_argument("--steps", type=positive_int, help="frames to predict (default: the horizon)")
    parser.add_argument("--video", choices=("gif", "mp4"), default="gif")
    add_reader_arguments(parser)
    return parser


def predict_main(argv: list[str] | None = None) -> int:
    args = predict_parser().parse_args(argv)
    from sb3_ef.offline.model import load_pretrained
    from sb3_ef.offline.predict import predict_episode
    from sb3_ef.offline.readers import open_dataset

    options = reader_options(args)
    model, _ = load_pretrained(args.model)
    dataset = open_dataset(args.dataset, min_frames=model.config.context + 1, **options)
    if not args.episode < len(dataset):
        raise ValueError(f"--episode {args.episode} is not in 0..{len(dataset) - 1} of {args.dataset}")
    written = predict_episode(model, dataset[args.episode], args.out, args.start, args.actions, args.steps, args.video)
    print(json.dumps(written, indent=2))
    return 0
