"""How fast sheeprl's Dreamer-v3 loop runs (acting, env steps, replay, gradient steps at the replay ratio), for
``gpu.py`` and ``throughput.py``: one training run that marks the time every few steps and evaluates and writes
nothing."""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

from sb3_ef.dreamerv3 import live
from sb3_ef.dreamerv3.config import Session
from sb3_ef.dreamerv3.dreamerv3 import DreamerV3
from sb3_ef.dreamerv3.env import task_id
from sb3_ef.dreamerv3.training import resolved_config, run


@dataclass(frozen=True)
class Mark:
    """The agent step sheeprl reached, with the wall-clock and process CPU time then (seconds)."""

    step: int
    wall_s: float
    cpu_s: float


class _Marker:
    """A Fabric callback in place of the checkpoint callback: it notes the time of each call."""

    def __init__(self) -> None:
        self.marks: list[Mark] = []

    def on_checkpoint_coupled(self, fabric: Any, ckpt_path: str, state: dict[str, Any], replay_buffer: Any = None):
        self.marks.append(Mark(int(state["iter_num"]), time.perf_counter(), time.process_time()))


def timed_training(model: DreamerV3, total_steps: int, every: int) -> list[Mark]:
    """Train a new run of ``model``'s settings on its env for ``total_steps`` agent steps, marking the time every
    ``every`` steps and at the end (``model`` itself keeps its weights; its work folder gets the run's files)."""
    if model.env is None:
        raise ValueError("timed_training needs a model with an env")
    marker = _Marker()
    (model.work_dir / "sheeprl" / "timing").mkdir(parents=True, exist_ok=True)  # sheeprl's runs, version_<n>
    with live.registered(model.env) as env_token, live.registered(marker) as marker_token:
        session = Session(
            env_token, marker_token, task_id(model.env), model.frame_shape[1], model.seed, total_steps, every, None,
            str(model.work_dir), "timing", model.device,
        )  # fmt: skip
        run(resolved_config(model.cfg.copy(), session))
    return marker.marks
