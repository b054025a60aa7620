"""Progress lines for long training runs, readable in a terminal and in a log file."""

from __future__ import annotations

import datetime
import time
from collections import deque

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback


def _clock(seconds: float) -> str:
    return str(datetime.timedelta(seconds=round(seconds)))


class ProgressLogCallback(BaseCallback):
    """Print the step, recent speed, elapsed and remaining time and the recent return every ``interval_s``.

    :param total_timesteps: the step the run trains to (``num_timesteps`` counts on across a resume).
    :param interval_s: least wall time between two lines.
    :param prefix: put before every line (e.g. the run's id when several runs print to one terminal).
    :param recent_s: the speed, and the time left from it, are those of about the last ``recent_s`` seconds (a
        random-action warm-up runs many times faster than training: a mean since the start would drift for hours).
    """

    def __init__(self, total_timesteps: int, interval_s: float = 10.0, prefix: str = "", recent_s: float = 60.0):
        super().__init__()
        self.total_timesteps, self.interval_s, self.prefix = total_timesteps, interval_s, prefix
        self.recent_s = recent_s
        self._start_time, self._last_line = 0.0, 0.0
        self._marks: deque[tuple[float, int]] = deque()  # (time, step) of the lines within about recent_s

    def _on_training_start(self) -> None:
        self._start_time = self._last_line = time.monotonic()
        self._marks = deque([(self._start_time, self.num_timesteps)])
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
        self._marks.append((now, self.num_timesteps))
        while len(self._marks) > 1 and now - self._marks[1][0] >= self.recent_s:
            self._marks.popleft()  # the first mark stays the newest one at least recent_s old
        since, step = self._marks[0]
        speed = (self.num_timesteps - step) / (now - since) if now > since else 0.0
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
