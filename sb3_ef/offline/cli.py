"""``sb3-ef collect``, ``sb3-ef pretrain`` and ``sb3-ef predict``: offline Ego-Foresight from the command line.

sb3-ef collect ENV OUT [--episodes 10] [--size 64] [--mode sign|clamped_uniform] [--policy MODEL.zip] ...
sb3-ef pretrain DATASET OUT [--encoder dcgan-unet|drqv2|tdmpc2] [--context 3] [--horizon 10] [--steps 10000] ...
sb3-ef predict MODEL OUT --dataset DATASET [--episode 0] [--start T] [--actions dataset|figure8] [--steps 30]
"""

from __future__ import annotations

import argparse
import json


def collect_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="sb3-ef collect", description="record episodes (frames, actions, masks)")
    parser.add_argument("env", help="env name, e.g. metaworld/hammer, dmc/reacher-easy, toy/agent-v0")
    parser.add_argument("out", help="output folder (one .npz or .h5 file per episode)")
    parser.add_argument("--episodes", type=int, default=10)
    parser.add_argument("--size", type=int, default=64, help="frame size (ignored with --policy: the model's)")
    parser.add_argument("--action-repeat", type=int, default=2)
    parser.add_argument("--mode", choices=("sign", "clamped_uniform"), default="sign", help="babbling actions")
    parser.add_argument("--policy", help="saved DrQv2EF / TDMPC2EF (.zip) acting instead of babbling")
    parser.add_argument("--algo", choices=("drqv2_ef", "tdmpc2_ef"), help="algorithm of --policy")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--slow-render", action="store_true", help="render shadows and reflections (slower)")
    parser.add_argument("--no-masks", action="store_true", help="skip the agent masks (one render less per step)")
    parser.add_argument("--format", choices=("npz", "h5"), default="npz")
    parser.add_argument("--no-progress", action="store_true")
    return parser


def collect_main(argv: list[str] | None = None) -> int:
    args = collect_parser().parse_args(argv)
    from sb3_ef.offline.collect import collect

    paths = collect(
        args.env,
        args.out,
        episodes=args.episodes,
        size=args.size,
        action_repeat=args.action_repeat,
        mode=args.mode,
        policy=args.policy,
        algo=args.algo,
        seed=args.seed,
        fast_render=not args.slow_render,
        masks=not args.no_masks,
        file_format=args.format,
        progress_bar=not args.no_progress,
    )
    print(f"Wrote {len(paths)} episodes to {args.out}")
    return 0


def pretrain_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="sb3-ef pretrain", description="train encoder + Ego-Foresight offline")
    parser.add_argument("dataset", help="episode folder (.npz/.h5), .tfrecord file or folder (BAIR), or minari:<id>")
    parser.add_argument("out", help="output folder: checkpoint.pt, model.pt, metrics.json, tb/")
    parser.add_argument("--encoder", choices=("dcgan-unet", "drqv2", "tdmpc2"), default="dcgan-unet")
    parser.add_argument("--context", type=int, default=3, help="stacked context frames (the RL frame stack)")
    parser.add_argument("--horizon", type=int, default=10, help="largest prediction step k")
    parser.add_argument("--agent-dim", type=int, default=32)
    parser.add_argument("--steps", type=int, default=10_000)
    parser.add_argument("--batch-size", type=int, default=32)
    parser.add_argument("--lr", type=float, default=1e-3)
    parser.add_argument("--shift-pad", type=int, default=0, help="random-shift augmentation in pixels (0: none)")
    parser.add_argument("--holdout", type=float, default=0.1, help="held-out episodes: a count, or a fraction < 1")
    parser.add_argument("--eval-every", type=int, default=1000)
    parser.add_argument("--checkpoint-every", type=int, default=500)
    parser.add_argument("--encoder-kwargs", type=json.loads, default={}, help="JSON, e.g. '{\"width\": 32}'")
    parser.add_argument("--ef-kwargs", type=json.loads, default={}, help="JSON, e.g. '{\"decoder_channels\": 32}'")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--threads", type=int, help="torch CPU threads (1 is fastest on a busy shared machine)")
    parser.add_argument("--no-resume", action="store_true", help="start over even if OUT/checkpoint.pt exists")
    parser.add_argument("--no-progress", action="store_true")
    return parser


def pretrain_main(argv: list[str] | None = None) -> int:
    args = pretrain_parser().parse_args(argv)
    from sb3_ef.offline.pretrain import pretrain

    if args.threads:
        import torch

        torch.set_num_threads(args.threads)
    holdout = args.holdout if args.holdout < 1 else int(args.holdout)
    _, scores = pretrain(
        args.dataset,
        args.out,
        encoder=args.encoder,
        context=args.context,
        horizon=args.horizon,
        agent_dim=args.agent_dim,
        steps=args.steps,
        batch_size=args.batch_size,
        learning_rate=args.lr,
        shift_pad=args.shift_pad,
        holdout=holdout,
        eval_every=args.eval_every,
        checkpoint_every=args.checkpoint_every,
        encoder_kwargs=args.encoder_kwargs,
        ef_kwargs=args.ef_kwargs,
        seed=args.seed,
        device=args.device,
        resume=not args.no_resume,
        progress_bar=not args.no_progress,
    )
    print(json.dumps({key: value for key, value in scores.items() if not isinstance(value, list)}, indent=2))
    return 0


def predict_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="sb3-ef predict", description="open-loop predictions of a pretrained model")
    parser.add_argument("model", help="model.pt or checkpoint.pt written by sb3-ef pretrain")
    parser.add_argument("out", help="output folder: prediction.png and prediction.gif / .mp4")
    parser.add_argument("--dataset", required=True, help="where the context frames come from (as for pretrain)")
    parser.add_argument("--episode", type=int, default=0)
    parser.add_argument("--start", type=int, help="last context frame (default: context - 1)")
    parser.add_argument("--actions", choices=("dataset", "figure8"), default="dataset")
    parser.add_argument("--steps", type=int, help="frames to predict (default: the horizon)")
    parser.add_argument("--video", choices=("gif", "mp4"), default="gif")
    return parser


def predict_main(argv: list[str] | None = None) -> int:
    args = predict_parser().parse_args(argv)
    from sb3_ef.offline.model import load_pretrained
    from sb3_ef.offline.predict import predict_episode
    from sb3_ef.offline.readers import open_dataset

    model, _ = load_pretrained(args.model)
    episode = open_dataset(args.dataset, min_frames=model.config.context + 1)[args.episode]
    written = predict_episode(model, episode, args.out, args.start, args.actions, args.steps, args.video)
    print(json.dumps(written, indent=2))
    return 0
