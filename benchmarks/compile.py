"""Updates/s of eager and compiled (``compile=...``) updates of DrQv2EF and TDMPC2EF, measured side by side, in
float32 and (``--precision fp32 bf16``) bfloat16 mixed precision.

The models of an algorithm are built alike (fast-rendering cartpole, buffer filled by warm-up steps, first updates
done, which for the compiled model includes compiling: its build time is reported); then ``train()`` is timed in
interleaved rounds and the medians are reported.

Usage (headless rendering needs EGL)::

    MUJOCO_GL=egl python benchmarks/compile.py --threads 1
    MUJOCO_GL=egl python benchmarks/compile.py --threads 1 --precision fp32 bf16
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from typing import Any

import torch as th
from throughput import Setting, build, timed

from sb3_ef.common.compile import COMPILE_MODES
from sb3_ef.common.precision import PRECISIONS
from sb3_ef.drqv2 import DrQv2EF
from sb3_ef.tdmpc2 import TDMPC2EF

# (name, class, frame size, algorithm kwargs).
ALGORITHMS: list[tuple[str, type, int, dict[str, Any]]] = [
    ("DrQv2EF", DrQv2EF, 84, {}),
    ("TDMPC2EF", TDMPC2EF, 64, {"seed_burst": False}),  # the warm-up's burst of updates is not measured
]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--algorithm", choices=[name for name, *_ in ALGORITHMS] + ["all"], default="all")
    parser.add_argument("--mode", choices=["True", *COMPILE_MODES], default="True", help="the compile option")
    parser.add_argument("--batch-size", type=int, default=32)
    parser.add_argument("--updates", type=int, default=10, help="updates per timed round")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--threads", type=int, default=1, help="torch intra-op threads")
    parser.add_argument(
        "--precision", nargs="+", choices=PRECISIONS, default=["fp32"], help="each one eager and compiled, interleaved"
    )
    args = parser.parse_args()
    th.set_num_threads(args.threads)
    compile_option = True if args.mode == "True" else args.mode

    device = "CUDA " + th.cuda.get_device_name() if th.cuda.is_available() else f"CPU, {args.threads} torch threads"
    print(f"{device}, compile={compile_option!r}, load average before: {os.getloadavg()[0]:.1f}")
    print(
        "| algorithm | frames, batch | precision | updates/s eager | updates/s compiled | compiled/eager "
        "| build s (eager, compiled) |"
    )
    print("|---|---|---|---|---|---|---|")
    for name, algorithm, size, kwargs in ALGORITHMS:
        if args.algorithm not in ("all", name):
            continue
        setting = Setting(size=size, batch_size=args.batch_size, warmup_steps=300, loop_steps=0, updates=args.updates)
        models, build_seconds = {}, {}
        for precision in args.precision:
            for variant, option in (("eager", False), ("compiled", compile_option)):
                start = time.perf_counter()
                options = {**kwargs, "babbling_steps": 0, "compile": option, "precision": precision}
                models[precision, variant] = build(algorithm, setting, options)
                build_seconds[precision, variant] = time.perf_counter() - start
        rates: dict[tuple[str, str], list[float]] = {key: [] for key in models}
        for _ in range(args.repeats):
            for key, model in models.items():
                wall, _ = timed(lambda m=model: m.train(args.updates, args.batch_size))
                rates[key].append(args.updates / wall)
        for precision in args.precision:
            eager, compiled = (statistics.median(rates[precision, variant]) for variant in ("eager", "compiled"))
            print(
                f"| {name} | {size}x{size}, {args.batch_size} | {precision} | {eager:.2f} | {compiled:.2f} "
                f"| {compiled / eager:.2f} | {build_seconds[precision, 'eager']:.0f}, "
                f"{build_seconds[precision, 'compiled']:.0f} |",
                flush=True,
            )
        for model in models.values():
            model.env.close()
    print(f"load average after: {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
