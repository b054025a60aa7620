"""Offline Ego-Foresight on a Meta-World babbling dataset: collect, pretrain the DCGAN U-Net model, held-out scores.

Run on purpose (not a test), e.g. in the background on a shared machine::

    MUJOCO_GL=egl nice -n 10 python benchmarks/offline.py --out /tmp/offline_bench --minutes 45

Collects ``--episodes`` babbling episodes of ``--env`` at 64x64 (skipped when OUT/data already holds them), then
pretrains in chunks of ``--chunk`` updates (resuming from OUT/run/checkpoint.pt, also across runs of this script)
while another chunk fits in ``--minutes`` of training, writing the held-out scores after every chunk to
OUT/results.jsonl: agent-pixel and full-frame error
against copying the last context frame over k = 1..H, and h_a saliency precision against chance.
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import time

import torch as th

from sb3_ef.offline.collect import collect
from sb3_ef.offline.pretrain import CHECKPOINT, pretrain


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", default="/tmp/offline_bench")
    parser.add_argument("--env", default="metaworld/hammer")
    parser.add_argument("--episodes", type=int, default=82, help="82 episodes of 251 frames: 20582 frames")
    parser.add_argument("--holdout", type=int, default=8)
    parser.add_argument("--chunk", type=int, default=500, help="updates between held-out evaluations")
    parser.add_argument("--minutes", type=float, default=45.0, help="training time budget (wall clock)")
    parser.add_argument("--batch-size", type=int, default=16)
    parser.add_argument("--width", type=int, default=32, help="DCGAN encoder width")
    parser.add_argument("--decoder-channels", type=int, default=32)
    parser.add_argument("--saliency-windows", type=int, default=16, help="held-out windows scored for saliency")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (1 avoids spinning on a busy machine)")
    args = parser.parse_args()
    th.set_num_threads(args.threads)

    data = os.path.join(args.out, "data")
    start = time.perf_counter()
    if len(glob.glob(os.path.join(data, "*.npz"))) < args.episodes:
        # Agent masks are only scored on the held-out episodes (the last ones): the others skip that render.
        held_out = range(args.episodes - args.holdout, args.episodes)
        collect(args.env, data, episodes=args.episodes, size=64, seed=0, masks=held_out)
    collect_seconds = time.perf_counter() - start
    print(json.dumps({"collect_seconds": collect_seconds}), flush=True)

    run = os.path.join(args.out, "run")
    checkpoint = os.path.join(run, CHECKPOINT)
    steps = th.load(checkpoint, weights_only=False)["step"] if os.path.isfile(checkpoint) else 0
    train_start, chunk_seconds = time.perf_counter(), 0.0
    while time.perf_counter() - train_start + chunk_seconds < 60 * args.minutes:
        chunk_start = time.perf_counter()
        steps += args.chunk
        _, scores = pretrain(
            data,
            run,
            encoder="dcgan-unet",
            steps=steps,
            batch_size=args.batch_size,
            holdout=args.holdout,
            eval_every=args.chunk,
            checkpoint_every=args.chunk,
            encoder_kwargs={"width": args.width},
            ef_kwargs={"decoder_channels": args.decoder_channels},
            saliency_windows=args.saliency_windows,
            progress_bar=False,
        )
        chunk_seconds = time.perf_counter() - chunk_start
        row = {"updates": steps, "train_minutes": (time.perf_counter() - train_start) / 60, **scores}
        with open(os.path.join(args.out, "results.jsonl"), "a") as file:
            file.write(json.dumps(row) + "\n")
        print(json.dumps({key: value for key, value in row.items() if not isinstance(value, list)}), flush=True)


if __name__ == "__main__":
    main()
