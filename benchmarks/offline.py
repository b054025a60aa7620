"""Offline Ego-Foresight on a Meta-World babbling dataset: collect, pretrain the DCGAN U-Net model, held-out scores.

Run on purpose (not a test), e.g. in the background on a shared machine::

    MUJOCO_GL=egl nice -n 10 python benchmarks/offline.py --out /tmp/offline_bench --minutes 45

Collects ``--episodes`` babbling episodes of ``--env`` at 64x64 (skipped when OUT/data already holds them), then
pretrains in chunks of ``--chunk`` updates (resuming from OUT/run/checkpoint.pt, also across runs of this script)
while another chunk fits in ``--minutes`` of training, writing the held-out scores after every chunk to
OUT/results.jsonl: agent-pixel and full-frame error
against copying the last context frame over k = 1..H, and h_a saliency precision against chance.

Two reading measurements (no training)::

    nice -n 19 python benchmarks/offline.py --measure streaming --out /tmp/stream_bench
    nice -n 19 python benchmarks/offline.py --measure crc

``streaming`` writes ``--stream-episodes`` synthetic 64x64 episodes (NPZ, and the same as a LeRobot AV1 dataset), then
in a fresh process each: draws ``--batches`` batches of 32 windows streamed with ``--cache-mb`` of episode cache (NPZ
and LeRobot), and loads a dataset that fits (``--fit-episodes``) and the large one whole (``load_episodes``); it
prints peak RSS, RSS after the imports, and windows/s. ``crc`` times TFRecord reading of 400 KB records with the C
CRC-32C and the pure-Python one.
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import resource
import subprocess
import sys
import time

import numpy as np
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
    parser.add_argument("--measure", choices=("streaming", "crc"), help="a reading measurement instead of training")
    parser.add_argument("--stream-episodes", type=int, default=120, help="episodes of the streamed dataset")
    parser.add_argument("--fit-episodes", type=int, default=20, help="episodes of the dataset loaded whole")
    parser.add_argument("--cache-mb", type=float, default=64)
    parser.add_argument("--batches", type=int, default=200)
    parser.add_argument("--run", nargs=2, metavar=("MODE", "PATH"), help=argparse.SUPPRESS)  # one child measurement
    args = parser.parse_args()
    th.set_num_threads(args.threads)
    if args.run:
        print(json.dumps(measure_reading(*args.run, args.cache_mb, args.batches)), flush=True)
        return
    if args.measure == "crc":
        print(json.dumps(measure_crc()), flush=True)
        return
    if args.measure == "streaming":
        measure_streaming(args)
        return

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


def measure_streaming(args: argparse.Namespace) -> None:
    """Write the datasets, then run each reading path in its own process (peak RSS is per process)."""
    from sb3_ef.offline.episodes import write_episode
    from sb3_ef.offline.lerobot import LeRobotWriter
    from tests.helpers.offline import square_episode

    paths = {name: os.path.join(args.out, name) for name in ("stream", "fit", "lerobot")}
    for name, count in (("stream", args.stream_episodes), ("fit", args.fit_episodes)):
        for index in range(count):
            path = os.path.join(paths[name], f"episode_{index:05d}.npz")
            if not os.path.exists(path):
                write_episode(path, square_episode(steps=200, size=64, seed=index))
    if not os.path.exists(os.path.join(paths["lerobot"], "meta", "info.json")):
        with LeRobotWriter(paths["lerobot"], (3, 64, 64), 2, masks=True) as writer:
            for index in range(args.stream_episodes):
                writer.add(square_episode(steps=200, size=64, seed=index))
    for mode, name in (("stream", "stream"), ("stream", "lerobot"), ("load", "fit"), ("load", "stream")):
        command = [sys.executable, __file__, "--run", mode, paths[name], "--cache-mb", str(args.cache_mb)]
        command += ["--batches", str(args.batches)]
        result = subprocess.run(command, capture_output=True, text=True, check=True, env={**os.environ, "SVT_LOG": "1"})
        print(result.stdout.strip().splitlines()[-1], flush=True)


def measure_reading(mode: str, path: str, cache_mb: float, batches: int) -> dict:
    """Draw ``batches`` batches of 32 windows (context 3, horizon 10) by one path; time and peak RSS."""
    import pyarrow.parquet  # noqa: F401  (imported by the LeRobot reader: counted in the baseline for every path)

    from sb3_ef.offline.readers import load_episodes, open_dataset
    from sb3_ef.offline.streaming import StreamingWindowSampler
    from sb3_ef.offline.windows import WindowSampler

    with open("/proc/self/status") as status:  # after the imports: what torch, numpy and pyarrow cost by themselves
        baseline = next(int(line.split()[1]) for line in status if line.startswith("VmRSS:")) / 1024
    start = time.perf_counter()
    dataset = open_dataset(path, min_frames=13)
    lengths = dataset.lengths()
    if mode == "stream":
        sampler = StreamingWindowSampler(dataset, range(len(dataset)), 3, 10, cache_mb, seed=0, lengths=lengths)
    else:
        sampler = WindowSampler(load_episodes(dataset), 3, 10, seed=0)
    ready = time.perf_counter()
    for _ in range(batches):
        sampler.sample(32)
    seconds = time.perf_counter() - ready
    frames = sum(lengths)
    return {
        "mode": mode,
        "dataset": os.path.basename(path),
        "episodes": len(lengths),
        "dataset_mb": round(frames * (3 * 64 * 64 + 64 * 64) / 2**20, 1),
        "cache_mb": cache_mb if mode == "stream" else None,
        "open_seconds": round(ready - start, 1),
        "windows_per_second": round(32 * batches / seconds, 1),
        "rss_after_imports_mb": round(baseline, 1),
        "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
    }


def measure_crc(records: int = 40, size: int = 400_000, repeats: int = 3) -> dict:
    """Records/s reading 400 KB TFRecord records with CRC checks, C vs pure Python, and without checks: the median
    of ``repeats`` passes (the pure-Python passes read the first 8 records only)."""
    import itertools
    import statistics
    import tempfile

    from sb3_ef.offline import tfrecord

    rng = np.random.default_rng(0)
    result: dict = {"implementation": tfrecord.CRC32C_IMPLEMENTATION, "record_bytes": size}
    with tempfile.TemporaryDirectory() as folder:
        path = os.path.join(folder, "a.tfrecord")
        tfrecord.write_records(path, [rng.integers(0, 256, size, dtype=np.uint8).tobytes() for _ in range(records)])
        c_crc = tfrecord._C_CRC32C
        modes = (("c", True, c_crc, records), ("python", True, None, 8), ("no_check", False, c_crc, records))
        for name, check, implementation, count in modes:
            tfrecord._C_CRC32C = implementation
            rates = []
            for _ in range(repeats):
                start = time.perf_counter()
                read = sum(1 for _ in itertools.islice(tfrecord.read_records(path, check_crc=check), count))
                rates.append(read / (time.perf_counter() - start))
            result[f"{name}_records_per_second"] = round(statistics.median(rates), 1)
        tfrecord._C_CRC32C = c_crc
    return result


if __name__ == "__main__":
    main()
