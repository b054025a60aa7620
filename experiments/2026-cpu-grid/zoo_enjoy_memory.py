"""Memory of a model loaded to act: SB3's plain ``load`` against the loader ``sb3-ef enjoy`` uses.

Saves a DrQv2EF with the paper's 84x84 networks whose saved ``buffer_size`` is the paper's (1M frames; the buffer
itself is never filled), then loads it in a fresh process each way and reports the replay buffer's allocated
capacity (``nbytes``, exact) and the process's resident memory after loading (pages the OS actually backs: NumPy's
zeroed arrays stay virtual until written, so RSS understates what filling the buffer would take).

    MUJOCO_GL=egl python experiments/2026-cpu-grid/zoo_enjoy_memory.py --buffer-size 1000000
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile

# Resident memory from /proc (Linux), in bytes.
_LOAD = """
import json, os, sys
from sb3_ef import DrQv2EF
from sb3_ef.zoo.enjoy import InferenceLoader
def rss():
    with open("/proc/self/statm") as statm:
        return int(statm.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
path, how = sys.argv[1], sys.argv[2]
before = rss()
model = DrQv2EF.load(path, device="cpu") if how == "plain" else InferenceLoader(DrQv2EF).load(path, device="cpu")
after = rss()
print(json.dumps({"frames": model.replay_buffer.buffer_size, "nbytes": model.replay_buffer.nbytes,
                  "rss_delta": after - before, "rss": after}))
"""


def save_model(path: str, buffer_size: int) -> None:
    """A paper-size DrQv2EF on 84x84 cheetah-run whose saved buffer_size is ``buffer_size``."""
    from sb3_ef import DrQv2EF, make_env

    env = make_env("dmc/cheetah-run", size=84, fast_render=True)
    model = DrQv2EF("CnnPolicy", env, buffer_size=1000, device="cpu")
    model.buffer_size = buffer_size  # what a paper run saves; building it here would only cost time
    model.save(path)
    env.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--buffer-size", type=int, default=1_000_000, help="saved replay buffer capacity (frames)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        path = os.path.join(folder, "model.zip")
        save_model(path, args.buffer_size)
        total = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        print(f"total RAM {total / 1e9:.1f} GB")
        print("| load | buffer frames | buffer bytes allocated | RSS after load | RSS added by load |")
        print("|---|---|---|---|---|")
        for how in ("plain", "enjoy"):
            result = subprocess.run([sys.executable, "-c", _LOAD, path, how], capture_output=True, text=True)
            if result.returncode != 0:
                print(f"| {how} | failed: {result.stderr.strip().splitlines()[-1]} | | | |")
                continue
            row = json.loads(result.stdout.strip().splitlines()[-1])
            print(
                f"| {how} | {row['frames']:,} | {row['nbytes'] / 1e9:.3f} GB | {row['rss'] / 1e9:.2f} GB "
                f"| {row['rss_delta'] / 1e9:.2f} GB |"
            )


if __name__ == "__main__":
    main()
