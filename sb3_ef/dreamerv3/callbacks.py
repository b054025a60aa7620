"""The Fabric callback of a Dreamer-v3 run: evaluation, then sheeprl's checkpoint, then the pointer to it.

sheeprl calls its checkpoint callback every ``checkpoint.every`` policy steps and at the end of training. There,
:class:`RunCallback`, in this order:

1. evaluates the checkpoint's weights (when the step is a multiple of the evaluation frequency) and appends the
   row to the run's evaluation CSV (:mod:`sb3_ef.analysis.records`);
2. writes sheeprl's checkpoint (weights, optimisers, replay buffer);
3. records the checkpoint as the run's latest in ``latest.json``, written atomically.

A run resumes from the checkpoint ``latest.json`` names, after dropping the evaluation rows past its step: a kill
at any point leaves either a row that the resumed run drops and writes again, or a checkpoint that is not yet
named and is not used, never a missing or a repeated row.
"""

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
    """Periodic evaluation of a run: ``n_episodes`` episodes on ``env`` (stacked frames, as sb3-ef's envs) every
    ``freq`` agent steps, seeded with :func:`~sb3_ef.common.evaluation.evaluation_seed` of ``seed`` and the step, one
    row per evaluation appended to ``records`` as ``algo`` / ``task`` with ``frame = step * action_repeat``. The
    actions are sampled from the policy, as the authors' evaluation mode does (``deterministic=True``: its mode)."""

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
    """The latest complete checkpoint of the run in ``work_dir``: ``{"checkpoint": path, "step": n, "settings":
    {...}}``, or ``None`` when it has none."""
    path = Path(work_dir) / LATEST_FILE
    if not path.is_file():
        return None
    latest = json.loads(path.read_text())
    if not Path(latest["checkpoint"]).is_file():
        raise FileNotFoundError(f"{path} names the checkpoint {latest['checkpoint']}, which does not exist")
    return latest


class RunCallback:
    """sheeprl's ``CheckpointCallback`` with the evaluation before it and ``latest.json`` after it (see the module
    docstring); keeps the newest checkpoint's state without its replay buffer in :attr:`last_state`.

    :param work_dir: the run's folder (``latest.json`` goes there).
    :param settings: what ``latest.json`` records to rebuild the model (``DreamerV3``'s arguments).
    :param evaluation: the periodic evaluation, or ``None``.
    :param keep_last: the newest checkpoints sheeprl keeps (all with ``None``).
    :param save_every: the steps between checkpoints written to disk (sheeprl calls the callback at every
        evaluation; the other calls only keep :attr:`last_state`).
    :param total_steps: the step of the run's last call, whose checkpoint is always written.
    :param on_weights: called with each call's state (without its replay buffer), the newest weights.
    """

    def __init__(
        self,
        work_dir: str | os.PathLike,
        settings: dict[str, Any],
        frame_shape: tuple[int, int, int],
        action_space: gym.spaces.Box,
        evaluation: Evaluation | None = None,
        keep_last: int | None = None,
        save_every: int = 1,
        total_steps: int = 0,
        on_weights: Callable[[dict[str, Any]], None] | None = None,
    ):
        from sheeprl.utils.callback import CheckpointCallback

        self.checkpointer = CheckpointCallback(keep_last=keep_last)
        self.work_dir = Path(work_dir)
        self.settings = settings
        self.frame_shape = frame_shape
        self.action_space = action_space
        self.evaluation = evaluation
        self.save_every, self.total_steps = save_every, total_steps
        self.log_prefix: str | None = None  # print a line per evaluation, after this prefix
        self.start_step = 0  # the step this call of learn starts from (for the speed in the lines)
        self._start_time = time.monotonic()
        self.config: Any = None  # the run's resolved sheeprl configuration, set before training starts
        self.last_state: dict[str, Any] | None = None
        self.on_weights = on_weights
        self.last_checkpoint: str | None = None

    def on_checkpoint_coupled(
        self, fabric: Any, ckpt_path: str, state: dict[str, Any], replay_buffer: Any = None
    ) -> None:
        step = int(state["iter_num"])  # policy steps: one env, one process
        if self.evaluation is not None and step % self.evaluation.freq == 0:
            self._evaluate(fabric, state, step)
        self.last_state = {key: value for key, value in state.items() if key != "rb"}
        if self.on_weights is not None:
            self.on_weights(self.last_state)
        if step % self.save_every and step < self.total_steps:
            return
        self.checkpointer.on_checkpoint_coupled(fabric, ckpt_path, state, replay_buffer)
        checkpoint = os.path.abspath(ckpt_path)
        latest = {"checkpoint": checkpoint, "step": step, "settings": self.settings}
        write_text_atomically(self.work_dir / LATEST_FILE, json.dumps(latest, indent=1))
        self.last_checkpoint = checkpoint

    def _evaluate(self, fabric: Any, state: dict[str, Any], step: int) -> None:
        assert self.evaluation is not None and self.config is not None
        evaluation = self.evaluation
        # A player with this checkpoint's weights, built without drawing from the training's random streams
        with forked_rng(fabric.device):
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
        """``step 2000/500000 (0.4%)  12 steps/s``: the speed over this call of ``learn`` (evaluations included)."""
        elapsed = time.monotonic() - self._start_time
        speed = (step - self.start_step) / elapsed if elapsed > 0 else 0.0
        return f"step {step}/{self.total_steps} ({100 * step / max(self.total_steps, 1):.1f}%)  {speed:.1f} steps/s"


def live_callback(token: str) -> Any:
    """Hydra target of the run's Fabric callback: the registered object (a :class:`RunCallback`, or the timing
    callback of :mod:`sb3_ef.dreamerv3.timing`), which sheeprl calls at its checkpoint steps."""
    callback = live.lookup(token)
    if not callable(getattr(callback, "on_checkpoint_coupled", None)):
        raise TypeError(f"{token!r} names a {type(callback).__name__}, which has no on_checkpoint_coupled")
    return callback
