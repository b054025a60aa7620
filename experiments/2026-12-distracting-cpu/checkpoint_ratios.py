"""``aux_grad_ratio`` of a grid's DrQv2EF runs over training, read from their checkpoints.

The grid runner keeps no SB3 log, so ``train/aux_grad_ratio`` is not written by the runs themselves; run with
``--keep-checkpoints all``, each keeps its model and replay buffer every 2000 steps, and this script loads each
checkpoint and measures the same quantity on ``--batches`` replay batches (``grad_share.gradient_share``: the
weighted EF loss's encoder-gradient norm over the critic loss's, with the run's own augmentation). One line per run
and checkpoint, then the mean over the runs per step.

    cd experiments/2026-12-distracting-cpu && MUJOCO_GL=egl python checkpoint_ratios.py results/latent-v2
"""

from __future__ import annotations

import argparse
from collections import defaultdict
from pathlib import Path

import numpy as np
import torch as th
from grad_share import gradient_share

from sb3_ef import DrQv2EF
from sb3_ef.common.checkpoints import list_checkpoints


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("results", type=Path, help="a grid's results folder (its runs' checkpoints below it)")
    parser.add_argument("--batches", type=int, default=4)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--steps", type=int, nargs="*", help="only the checkpoints of these steps (default: all)")
    args = parser.parse_args()
    th.set_num_threads(1)
    by_step: dict[int, list[float]] = defaultdict(list)
    print("run\tstep\taux_grad_ratio mean [min, max]\tcritic norm\tEF norm")
    for folder in sorted(args.results.glob("*/*/checkpoints")):
        for checkpoint in list_checkpoints(folder):
            if checkpoint.replay_buffer_path is None or (args.steps and checkpoint.step not in args.steps):
                continue
            model = DrQv2EF.load(checkpoint.model_path, device="cpu")
            model.load_replay_buffer(checkpoint.replay_buffer_path)
            ratios, critic, ef = gradient_share(model, args.batches, args.seed)
            by_step[checkpoint.step].append(float(np.mean(ratios)))
            run = folder.parent.relative_to(args.results)
            print(
                f"{run}\t{checkpoint.step}\t{np.mean(ratios):.3f} [{min(ratios):.3f}, {max(ratios):.3f}]\t"
                f"{np.mean(critic):.2f}\t{np.mean(ef):.2f}",
                flush=True,
            )
    for step, values in sorted(by_step.items()):
        print(f"mean over {len(values)} runs\t{step}\t{np.mean(values):.3f}")


if __name__ == "__main__":
    main()
