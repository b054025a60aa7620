"""A ``dreamerv3`` row of ``sb3-ef benchmark`` and ``sb3-ef train``: the grid's files and resume rule."""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

from sb3_ef.common.evaluation import EVAL_SEED_OFFSET
from sb3_ef.common.interrupt import Interrupted
from sb3_ef.grid.grid import RunSpec, constructor_kwargs
from sb3_ef.grid.run import (
    RunPaths,
    build_env,
    truncate_records,
)

if TYPE_CHECKING:
    import gymnasium as gym

    from sb3_ef.dreamerv3 import DreamerV3

#: The zoo keys the runner sets itself.
RUNNER_SET = ("work_dir", "seed", "device")


def new_dreamerv3(spec: RunSpec, env: gym.Env, device: str, work_dir: Path) -> DreamerV3:
    """The model of a ``dreamerv3`` run that starts anew, on ``env``, writing into ``work_dir``."""
    from sb3_ef.dreamerv3 import DreamerV3

    if spec.vectorized:
        raise ValueError(f"{spec.run_id}: DreamerV3 trains on one env; n_envs > 1 and env_wrapper are not supported")
    given = sorted(set(RUNNER_SET) & set(spec.hyperparams))
    if given:
        raise ValueError(f"{spec.run_id}: {given} are set by the runner, not by the hyperparameters")
    kwargs = constructor_kwargs(dict(spec.hyperparams))
    return DreamerV3(env=env, seed=spec.seed, device=device, work_dir=work_dir, **kwargs)


def check_dreamerv3_row(spec: RunSpec, env: gym.Env, device: str) -> None:
    """The grid check of a ``dreamerv3`` row: its model built on ``env``, nothing trained or written."""
    new_dreamerv3(spec, env, device, Path(tempfile.gettempdir(), "sb3_ef_dreamerv3_check"))


def train_dreamerv3(
    spec: RunSpec, paths: RunPaths, threads: int, device: str, keep_checkpoints: int | None
) -> tuple[int, int | None]:
    """Train (or resume) the run of ``spec``; return the steps trained and the step it resumed from, if any."""
    import torch as th

    from sb3_ef.dreamerv3 import DreamerV3, Evaluation

    th.set_num_threads(threads)
    env = build_env(spec, seed=spec.seed)
    eval_env = build_env(spec, seed=spec.seed + EVAL_SEED_OFFSET)
    model = DreamerV3.resume(paths.checkpoints, env, device=device)
    if model is None:
        paths.records.unlink(missing_ok=True)
        shutil.rmtree(paths.checkpoints, ignore_errors=True)  # a run killed before its first checkpoint
        model = new_dreamerv3(spec, env, device, paths.checkpoints)
        resumed_from: int | None = None
    else:
        resumed_from = model.num_timesteps
        truncate_records(paths.records, resumed_from)
    evaluation = Evaluation(
        eval_env,
        freq=spec.eval_freq,
        n_episodes=spec.eval_episodes,
        records=paths.records,
        algo=DreamerV3.__name__ if spec.label == spec.algo else spec.label,
        task=spec.task,
        seed=spec.seed,
        action_repeat=spec.action_repeat,
    )
    remaining = spec.n_timesteps - model.num_timesteps
    if remaining > 0:
        print(f"[{spec.run_id}] Training from step {model.num_timesteps} to {spec.n_timesteps}", flush=True)
        try:
            model.learn(
                remaining,
                reset_num_timesteps=resumed_from is None,
                evaluation=evaluation,
                checkpoint_freq=spec.checkpoint_freq,
                keep_checkpoints=keep_checkpoints,
                log_prefix=f"[{spec.run_id}] ",
            )
        except KeyboardInterrupt:
            raise Interrupted(_saved_on_interrupt(model, paths)) from None
    model.save(paths.model)
    env.close()
    eval_env.close()
    return model.num_timesteps, resumed_from


def _saved_on_interrupt(model: DreamerV3, paths: RunPaths) -> str:
    """Save the newest weights of a run stopped by Ctrl-C as its model; what was kept and where the run resumes."""
    from sb3_ef.dreamerv3.callbacks import read_latest

    latest = read_latest(paths.checkpoints)
    resumes = f"its last checkpoint is at step {latest['step']}" if latest else "it has no checkpoint yet"
    if model.num_timesteps == 0:
        return f"stopped before its first step, no model saved; {resumes}"
    model.save(paths.model)
    return f"stopped at step {model.num_timesteps}, model saved to {paths.model}; {resumes}"
