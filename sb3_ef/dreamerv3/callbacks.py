"""The Fabric callback sheeprl calls after every step: evaluate, write a checkpoint, name it in ``latest.json``, call
SB3's callbacks (in that order)."""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym

from sb3_ef.analysis.records import append_records, record_row
from sb3_ef.common.evaluation import evaluation_seed
from sb3_ef.common.files import write_text_atomically
from sb3_ef.dreamerv3 import live
from sb3_ef.dreamerv3.player import Player, forked_rng, run_episodes

#: The file naming a run's latest complete checkpoint, in the run's work folder.
LATEST_FILE = "latest.json"


@dataclass(frozen=True)
class Evaluation:
    """``n_episodes`` seeded episodes on ``env`` every ``freq`` agent steps, a CSV row each (actions sampled)."""

    env: gym.Env
    freq: int
    n_episodes: int
    records: str | os.PathLike[str]
    algo: str
    task: str
    seed: int
    action_repeat: int
    deterministic: bool = False

    def __post_init__(self) -> None:
        for name in ("freq", "n_episodes", "action_repeat"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"Evaluation {name} must be a positive integer, got {value!r}")


def read_latest(work_dir: str | os.PathLike) -> dict[str, Any] | None:
    """``{"checkpoint", "step", "settings", "replay_buffer"}`` of the run's latest complete checkpoint, or ``None``."""
    path = Path(work_dir) / LATEST_FILE
    if not path.is_file():
        return None
    latest = json.loads(path.read_text())
    if not Path(latest["checkpoint"]).is_file():
        raise FileNotFoundError(f"{path} names the checkpoint {latest['checkpoint']}, which does not exist")
    return {"replay_buffer": True, **latest}  # files written before the key existed held the buffer


class StopTraining(BaseException):
    """An SB3 callback returned ``False`` (a ``BaseException``: no ``except Exception`` on the way out catches it)."""


class RunCallback:
    """sheeprl's ``CheckpointCallback`` called after every step: the model takes the state, then the evaluation, the
    checkpoint and ``latest.json`` at their steps, then SB3's callbacks (in that order).

    :param work_dir: the run's folder (``latest.json`` goes there).
    :param settings: ``DreamerV3``'s arguments, recorded in ``latest.json``.
    :param on_weights: called with each step's state without its replay buffer.
    :param on_checkpoint: called with each checkpoint written and whether it holds the replay buffer.
    :param on_step: SB3's ``callback.on_step``; when it returns ``False`` the step's checkpoint is written (the
        model continues from it) and :class:`StopTraining` is raised.
    :param evaluation: the periodic evaluation, or ``None``.
    :param keep_last: the newest checkpoints sheeprl keeps (all with ``None``).
    :param save_every: the steps between checkpoints written to disk.
    :param total_steps: the step of the run's last call, whose checkpoint is always written.
    """

    def __init__(
        self,
        work_dir: str | os.PathLike,
        settings: dict[str, Any],
        frame_shape: tuple[int, int, int],
        action_space: gym.spaces.Box,
        on_weights: Callable[[dict[str, Any]], None],
        on_checkpoint: Callable[[str, bool], None],
        on_step: Callable[[], bool],
        evaluation: Evaluation | None = None,
        keep_last: int | None = None,
        save_every: int = 1,
        total_steps: int = 0,
    ):
        from sheeprl.utils.callback import CheckpointCallback

        self.checkpointer = CheckpointCallback(keep_last=keep_last)
        self.work_dir, self.settings, self.evaluation = Path(work_dir), settings, evaluation
        self.frame_shape, self.action_space = frame_shape, action_space
        self.save_every, self.total_steps = save_every, total_steps
        self.on_weights, self.on_checkpoint, self.on_step = on_weights, on_checkpoint, on_step
        self.log_prefix: str | None = None  # print a line per evaluation, after this prefix
        self.start_step = 0  # the step this call of learn starts from (for the speed in the lines)
        self._start_time = time.monotonic()
        self.config: Any = None  # the run's resolved sheeprl configuration, set before training starts

    def on_checkpoint_coupled(
        self, fabric: Any, ckpt_path: str, state: dict[str, Any], replay_buffer: Any = None
    ) -> None:
        step = int(state["iter_num"])  # policy steps: one env, one process
        weights = {key: value for key, value in state.items() if key != "rb"}
        self.on_weights(weights)
        if self.evaluation is not None and step % self.evaluation.freq == 0:
            self._evaluate(fabric, weights, step)
        written = step % self.save_every == 0 or step >= self.total_steps
        if written:
            self._write(fabric, ckpt_path, state, replay_buffer)
        if not self.on_step():
            if not written:
                self._write(fabric, ckpt_path, state, replay_buffer)
            raise StopTraining(f"a callback stopped the training at step {step}")

    def _write(self, fabric: Any, ckpt_path: str, state: dict[str, Any], replay_buffer: Any) -> None:
        """sheeprl's checkpoint, then ``latest.json`` naming it."""
        self.checkpointer.on_checkpoint_coupled(fabric, ckpt_path, state, replay_buffer)
        checkpoint = os.path.abspath(ckpt_path)
        latest = {
            "checkpoint": checkpoint, "step": int(state["iter_num"]), "settings": self.settings,
            "replay_buffer": replay_buffer is not None,
        }  # fmt: skip
        write_text_atomically(self.work_dir / LATEST_FILE, json.dumps(latest, indent=1))
        self.on_checkpoint(checkpoint, replay_buffer is not None)

    def _evaluate(self, fabric: Any, state: dict[str, Any], step: int) -> None:
        assert self.evaluation is not None and self.config is not None
        evaluation = self.evaluation
        with forked_rng(fabric.device):  # the training's random stream untouched
            player = Player(fabric, self.config, self.frame_shape, self.action_space, state)
        seed = evaluation_seed(evaluation.seed, step)
        mean_return, success = run_episodes(
            player, evaluation.env, evaluation.n_episodes, seed, evaluation.deterministic
        )
        row = record_row(
            evaluation.algo, evaluation.task, evaluation.seed, step, evaluation.action_repeat, mean_return, success
        )
        append_records(evaluation.records, [row])
        if self.log_prefix is not None:
            print(f"{self.log_prefix}{self._progress(step)}  return {mean_return:.1f} (evaluation)", flush=True)

    def _progress(self, step: int) -> str:
        """``step 2000/500000 (0.4%)  12 steps/s``, over this call of ``learn``."""
        elapsed = time.monotonic() - self._start_time
        speed = (step - self.start_step) / elapsed if elapsed > 0 else 0.0
        return f"step {step}/{self.total_steps} ({100 * step / max(self.total_steps, 1):.1f}%)  {speed:.1f} steps/s"


def live_callback(token: str) -> Any:
    """Hydra target of the run's Fabric callback: the registered object with ``on_checkpoint_coupled``."""
    callback = live.lookup(token)
    if not callable(getattr(callback, "on_checkpoint_coupled", None)):
        raise TypeError(f"{token!r} names a {type(callback).__name__}, which has no on_checkpoint_coupled")
    return callback
