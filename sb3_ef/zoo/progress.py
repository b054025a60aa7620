"""Progress lines for long training runs, readable in a terminal and in a log file."""

from __future__ import annotations

import datetime
import time

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback


def _clock(seconds: float) -> str:
    return str(datetime.timedelta(seconds=round(seconds)))


class ProgressLogCallback(BaseCallback):
    """Print the step, speed, elapsed and remaining time and the recent return every ``interval_s``.

    :param total_timesteps: the step the run trains to (``num_timesteps`` counts on across a resume).
    :param interval_s: least wall time between two lines.
    :param prefix: put before every line (e.g. the run's id when several runs print to one terminal).
    """

    def __init__(self, total_timesteps: int, interval_s: float = 10.0, prefix: str = ""):
        super().__init__()
        self.total_timesteps, self.interval_s, self.prefix = total_timesteps, interval_s, prefix
        self._start_time, self._start_step, self._last_line = 0.0, 0, 0.0

    def _on_training_start(self) -> None:
        self._start_time = self._last_line = time.monotonic()
        self._start_step = self.num_timesteps
        print(f"{self.prefix}Training from step {self.num_timesteps} to {self.total_timesteps}", flush=True)

    def _on_step(self) -> bool:
        now = time.monotonic()
        if now - self._last_line >= self.interval_s:
            self._last_line = now
            print(f"{self.prefix}{self.line(now)}", flush=True)
        return True

    def line(self, now: float) -> str:
        """The progress line at wall time ``now`` (``time.monotonic``)."""
        elapsed = now - self._start_time
        done = self.num_timesteps - self._start_step
        speed = done / elapsed if elapsed > 0 else 0.0
        text = (
            f"step {self.num_timesteps}/{self.total_timesteps} ({100 * self.num_timesteps / self.total_timesteps:.1f}%)"
        )
        text += f"  {speed:.0f} steps/s  elapsed {_clock(elapsed)}"
        if speed > 0:
            text += f"  left ~{_clock((self.total_timesteps - self.num_timesteps) / speed)}"
        episodes = self.model.ep_info_buffer
        if episodes:
            recent = [info["r"] for info in list(episodes)[-10:]]
            text += f"  return {np.mean(recent):.1f} (mean of the last {len(recent)} episodes)"
        return text
