"""One benchmark run: train with periodic evaluation, record, checkpoint, resume (files: docs/benchmark.md)."""

from __future__ import annotations

import json
import os
import shutil
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypedDict

import gymnasium as gym

from sb3_ef.analysis.records import (
    RECORD_COLUMNS,
    RUN_RESULT_FILE,
    EvalRecorderCallback,
    read_records,
    truncate_records,
    write_records,
)
from sb3_ef.common.evaluation import EVAL_SEED_OFFSET, StepSeededEvalCallback
from sb3_ef.common.files import write_text_atomically
from sb3_ef.envs.factory import MAKE_ENV_SUITES
from sb3_ef.envs.registration import is_atari, register_atari
from sb3_ef.grid.grid import RunSpec, algorithm_class, constructor_kwargs
from sb3_ef.registry import import_target

if TYPE_CHECKING:
    from stable_baselines3.common.noise import ActionNoise
    from stable_baselines3.common.vec_env import VecEnv

#: The training function (``"module:function"``) of each registry key that SB3's ``learn`` does not train, by path,
#: as it lives in that algorithm's workbench package, above the grid; the others train with :func:`train_sb3`.
GRID_RUNS = {"dreamerv3": "sb3_ef.dreamerv3.grid_run:train_dreamerv3"}


@dataclass(frozen=True)
class RunResult:
    """How a run ended (``done``, ``skipped`` or ``failed``), its evaluation records and its Ray node."""

    run_id: str
    status: str
    steps: int = 0
    duration_s: float = 0.0
    final_return: float | None = None
    resumed_from: int | None = None
    records: list[dict[str, Any]] = field(default_factory=list)
    error: str | None = None
    node: str | None = None


@dataclass(frozen=True)
class RunPaths:
    """Where a run's files live (module docstring); :meth:`of` gives a grid run's."""

    records: Path
    folder: Path
    final_model: Path | None = None

    @classmethod
    def of(cls, out: str | os.PathLike, spec: RunSpec) -> RunPaths:
        base = Path(out) / spec.run_id
        return cls(records=base.with_name(base.name + ".csv"), folder=base)

    @property
    def checkpoints(self) -> Path:
        return self.folder / "checkpoints"

    @property
    def result(self) -> Path:
        return self.folder / RUN_RESULT_FILE

    @property
    def model(self) -> Path:
        return self.final_model or self.folder / "model.zip"


def read_result(paths: RunPaths) -> RunResult | None:
    """The stored result of a finished run, as ``skipped``; ``None`` if the run has not finished."""
    if not paths.result.is_file():
        return None
    stored = json.loads(paths.result.read_text())
    return RunResult(**{**stored, "status": "skipped"})


def store_result(paths: RunPaths, result: RunResult) -> None:
    """Write a finished run's records (unless present), then its ``result.json`` (unless present)."""
    if paths.result.is_file():
        return
    if not paths.records.is_file():
        write_records(paths.records, result.records)
    paths.folder.mkdir(parents=True, exist_ok=True)
    write_text_atomically(paths.result, json.dumps(asdict(result), indent=1))


def build_env(spec: RunSpec, seed: int) -> gym.Env:
    """The run's env: :func:`sb3_ef.make_env` for the suites of ``MAKE_ENV_SUITES``, ``gym.make`` otherwise."""
    if spec.task.startswith(MAKE_ENV_SUITES):
        from sb3_ef.envs import make_env

        return make_env(spec.task, seed=seed, **spec.env_kwargs)
    register_atari(spec.task)
    return gym.make(spec.task, **spec.env_kwargs)


def build_vec_env(spec: RunSpec, seed: int, n_envs: int) -> VecEnv:
    """``n_envs`` of the run's envs as rl-zoo3 builds them: seeded ``seed + i``, each monitored inside the entry's
    ``env_wrapper`` (so an evaluation reads whole games' unclipped returns), frames stacked by ``VecFrameStack``, and
    channels-last images transposed as SB3 transposes the training envs."""
    from rl_zoo3.utils import get_wrapper_class
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.preprocessing import is_image_space, is_image_space_channels_first
    from stable_baselines3.common.vec_env import VecFrameStack, VecTransposeImage

    wrapper = get_wrapper_class({"env_wrapper": spec.env_wrapper}) if spec.env_wrapper is not None else None
    envs = make_vec_env(lambda: build_env(spec, seed), n_envs, seed=seed, wrapper_class=wrapper)
    if spec.frame_stack:
        envs = VecFrameStack(envs, spec.frame_stack)
    space = envs.observation_space
    if is_image_space(space) and not is_image_space_channels_first(space):  # type: ignore[arg-type]
        envs = VecTransposeImage(envs)
    return envs


def build_training_env(spec: RunSpec, seed: int) -> gym.Env | VecEnv:
    """The env a run trains on: its one env, or rl-zoo3's vectorised envs where the entry asks for them."""
    return build_vec_env(spec, seed, spec.n_envs) if spec.vectorized else build_env(spec, seed)


def build_eval_env(spec: RunSpec, seed: int) -> VecEnv:
    """One monitored env seeded with ``seed + EVAL_SEED_OFFSET``, so its episodes differ from the training ones."""
    return build_vec_env(spec, seed + EVAL_SEED_OFFSET, n_envs=1)


def action_noise(noise_type: Any, noise_std: Any, action_space: gym.Space) -> ActionNoise:
    """SB3's action noise of rl-zoo3's ``noise_type`` and ``noise_std`` keys, built as rl-zoo3 builds it."""
    import numpy as np
    from stable_baselines3.common.noise import NormalActionNoise, OrnsteinUhlenbeckActionNoise

    kinds = {"normal": NormalActionNoise, "ornstein-uhlenbeck": OrnsteinUhlenbeckActionNoise}
    if noise_type not in kinds:
        raise ValueError(f"noise_type must be one of {', '.join(map(repr, kinds))}, got {noise_type!r}")
    if isinstance(noise_std, bool) or not isinstance(noise_std, (int, float)) or not noise_std >= 0:
        raise ValueError(f"noise_std must be a number >= 0 (with noise_type {noise_type!r}), got {noise_std!r}")
    if not isinstance(action_space, gym.spaces.Box):
        raise ValueError(f"noise_type {noise_type!r} needs a continuous (Box) action space, got {action_space}")
    size = int(np.prod(action_space.shape))
    return kinds[noise_type](mean=np.zeros(size), sigma=noise_std * np.ones(size))


def new_model(spec: RunSpec, env: gym.Env | VecEnv, device: str, **options: Any) -> Any:
    """The algorithm of a run that starts anew, on ``env``, with the run's hyperparameters and ``options``."""
    kwargs = constructor_kwargs(dict(spec.hyperparams))
    if "noise_type" in kwargs or "noise_std" in kwargs:
        noise = kwargs.pop("noise_type", None), kwargs.pop("noise_std", None)
        kwargs["action_noise"] = action_noise(*noise, env.action_space)
    return algorithm_class(spec.algo)(env=env, seed=spec.seed, device=device, **kwargs, **options)


class RunOptions(TypedDict):
    """:func:`execute_run`'s options that a backend passes to every run."""

    threads: int
    device: str
    keep_checkpoints: int | None


def execute_run(
    spec: RunSpec,
    out: str | os.PathLike,
    threads: int = 1,
    device: str = "auto",
    keep_checkpoints: int | None = 2,
    node: str | None = None,
) -> RunResult:
    """Train and record one run with the registry's training function of ``spec.algo``, or return the stored result
    of a finished one."""
    paths = RunPaths.of(out, spec)
    finished = read_result(paths)
    if finished is not None:
        return finished
    algorithm_class(spec.algo, "RunSpec.algo")  # a known key
    train = import_target(GRID_RUNS[spec.algo]) if spec.algo in GRID_RUNS else train_sb3
    start = time.perf_counter()
    steps, resumed_from = train(spec, paths, threads, device, keep_checkpoints)
    return finish_run(spec, paths, steps, start, resumed_from, node, keep_checkpoints)


def train_sb3(
    spec: RunSpec, paths: RunPaths, threads: int, device: str, keep_checkpoints: int | None
) -> tuple[int, int | None]:
    """The grid's training of an algorithm SB3's ``learn`` trains: from scratch or its latest checkpoint to
    ``spec.n_timesteps``; returns the steps reached and the step it resumed from (``None``: from scratch)."""
    import torch as th

    from sb3_ef.common.checkpoints import ResumableCheckpointCallback, latest_checkpoint, load_checkpoint
    from sb3_ef.zoo.progress import ProgressLogCallback

    th.set_num_threads(threads)
    env = build_training_env(spec, seed=spec.seed)
    eval_env = build_eval_env(spec, spec.seed)
    algo_class = algorithm_class(spec.algo)
    checkpoint = latest_checkpoint(paths.checkpoints)
    if checkpoint is None:
        paths.records.unlink(missing_ok=True)
        model = new_model(spec, env, device)
        resumed_from: int | None = None
    else:
        model = load_checkpoint(algo_class, checkpoint, env, device=device)
        resumed_from = model.num_timesteps
        truncate_records(paths.records, resumed_from)
    # Records name an algorithm by its class; a variant keeps its own label, apart from the default.
    record_name = algo_class.__name__ if spec.label == spec.algo else spec.label
    recorder = EvalRecorderCallback(
        paths.records, algo=record_name, task=spec.task, seed=spec.seed, action_repeat=spec.action_repeat
    )
    # The deterministic action, but a sampled one on Atari, as rl-zoo3 evaluates (a greedy policy can loop there).
    evaluation = StepSeededEvalCallback(
        eval_env, spec.seed, eval_freq=spec.eval_freq // spec.n_envs, n_eval_episodes=spec.eval_episodes,
        callback_after_eval=recorder, deterministic=not is_atari(spec.task), verbose=0,
    )  # fmt: skip
    # Checkpoints are written at the start of the rollout after their step, so after that step's evaluation.
    callbacks = [
        evaluation,
        ResumableCheckpointCallback(spec.checkpoint_freq // spec.n_envs, str(paths.checkpoints), keep=keep_checkpoints),
        ProgressLogCallback(spec.n_timesteps, prefix=f"[{spec.run_id}] "),
    ]
    remaining = spec.n_timesteps - model.num_timesteps
    if remaining > 0:
        model.learn(remaining, callback=callbacks, reset_num_timesteps=resumed_from is None)
    model.save(paths.model)  # without the replay buffer (SB3 excludes it)
    env.close()
    eval_env.close()
    return model.num_timesteps, resumed_from


def finish_run(
    spec: RunSpec,
    paths: RunPaths,
    steps: int,
    start: float,
    resumed_from: int | None,
    node: str | None,
    keep_checkpoints: int | None,
) -> RunResult:
    """Store the result of a run that reached its steps, then remove its checkpoints unless all are kept."""
    records = read_records(paths.records)
    result = RunResult(
        run_id=spec.run_id,
        status="done",
        steps=steps,
        duration_s=time.perf_counter() - start,
        final_return=records[-1]["return"] if records else None,
        resumed_from=resumed_from,
        records=[{key: row[key] for key in RECORD_COLUMNS} for row in records],
        node=node,
    )
    store_result(paths, result)
    if keep_checkpoints is not None:
        shutil.rmtree(paths.checkpoints, ignore_errors=True)
    return result
