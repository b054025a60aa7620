"""rl-zoo3 runs that continue from resumable checkpoints (:class:`ResumingExperimentManager`, docs/zoo.md)."""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from rl_zoo3.exp_manager import ExperimentManager
from rl_zoo3.utils import ALGOS
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import CheckpointCallback, EvalCallback, ProgressBarCallback
from stable_baselines3.common.vec_env import VecEnv

from sb3_ef.analysis.records import EvalRecorderCallback, truncate_records
from sb3_ef.common.checkpoints import (
    Checkpoint,
    ResumableCheckpointCallback,
    checkpoint_for,
    latest_checkpoint,
    load_checkpoint,
)
from sb3_ef.common.evaluation import StepSeededEvalCallback
from sb3_ef.common.interrupt import Interrupted
from sb3_ef.zoo.progress import ProgressLogCallback
from sb3_ef.zoo.records import finish_run, run_records_path, run_result_path

#: File in ``<run>/<env>/`` holding the sb3-ef train arguments of the run (read by ``--resume``).
ARGV_FILE = "train_argv.json"


@dataclass(frozen=True)
class CheckpointOptions:
    """What ``--save-freq`` checkpoints hold: the replay buffer or not, and how many are kept."""

    include_buffer: bool = False
    keep: int = 2


def recorded_argv(run_dir: str | os.PathLike) -> tuple[Path, list[str]]:
    """The ``<env>`` folder of the sb3-ef run in ``run_dir`` and the train arguments it recorded, for ``--resume``."""
    folder = Path(run_dir)
    saved = sorted(folder.glob(f"*/{ARGV_FILE}"))
    if not folder.is_dir() or len(saved) != 1:
        raise ValueError(
            f"--resume expects an sb3-ef run folder holding <env>/{ARGV_FILE}, got {str(run_dir)!r} "
            f"({'not a folder' if not folder.is_dir() else f'{len(saved)} such files'})"
        )
    return saved[0].parent, json.loads(saved[0].read_text())


def with_seed(argv: list[str], seed: int) -> list[str]:
    """``argv`` ending with ``--seed seed`` unless it already gives that seed (rl-zoo3 draws one for ``-1``)."""
    parser = argparse.ArgumentParser(add_help=False, allow_abbrev=False)
    parser.add_argument("--seed", type=int, default=-1)
    given, _ = parser.parse_known_args(argv)
    return argv if given.seed == seed else [*argv, "--seed", str(seed)]


def outermost_missing(path: Path) -> Path | None:
    """The outermost of ``path`` and its parents that does not exist yet (what creating ``path`` creates)."""
    missing = None
    while not path.exists():
        missing, path = path, path.parent
    return missing


def continue_evaluations(callback: EvalCallback) -> None:
    """Start ``callback`` from the evaluations its ``evaluations.npz`` holds (new ones appended, the best kept)."""
    path = f"{callback.log_path}.npz" if callback.log_path is not None else None
    if path is None or not os.path.isfile(path):
        return
    with np.load(path) as evaluations:
        callback.evaluations_timesteps = evaluations["timesteps"].tolist()
        callback.evaluations_results = evaluations["results"].tolist()
        callback.evaluations_length = evaluations["ep_lengths"].tolist()
        if "successes" in evaluations.files:
            callback.evaluations_successes = evaluations["successes"].tolist()
    if callback.evaluations_results:
        callback.best_mean_reward = max(float(np.mean(returns)) for returns in callback.evaluations_results)


def resume_note(run_dir: str | os.PathLike, resume_command: str) -> str:
    """Where a run that stopped part-way in ``run_dir`` continues from, with ``resume_command``."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a damaged newest checkpoint is passed over: the note names the one used
        checkpoint = latest_checkpoint(run_dir, intact=True)
    if checkpoint is None:
        return f"The run in {run_dir} saved no checkpoint to resume from (checkpoints need --save-freq)"
    return (
        f"The run's last checkpoint is {checkpoint.model_path} (step {checkpoint.step}): continue with "
        f"`{resume_command}`"
    )


@contextmanager
def noting_last_checkpoint(run_dir: str | os.PathLike, resume_command: str) -> Iterator[None]:
    """Add :func:`resume_note` to an error that escapes the block (Ctrl-C passes unchanged)."""
    try:
        yield
    except Exception as error:
        error.add_note(resume_note(run_dir, resume_command))
        raise


class _Watched:
    """A model whose ``learn`` records a Ctrl-C (rl-zoo3 swallows it) and keeps its counters when ``continuing``."""

    def __init__(self, model: BaseAlgorithm, continuing: bool):
        self._model, self._continuing = model, continuing
        self.interrupted = False

    def learn(self, total_timesteps: int, **kwargs: Any) -> BaseAlgorithm:
        if self._continuing:
            kwargs["reset_num_timesteps"] = False
        try:
            return self._model.learn(total_timesteps, **kwargs)
        except KeyboardInterrupt:
            self.interrupted = True
            raise

    def __getattr__(self, name: str) -> Any:
        return getattr(self._model, name)


class ResumingExperimentManager(ExperimentManager):
    """rl-zoo3's ``ExperimentManager`` with resumable checkpoints and a ``-i`` that continues the run.

    :param args, kwargs: rl-zoo3's ``ExperimentManager`` arguments.
    :param checkpoint_options: what checkpoints hold.
    :param argv: the sb3-ef train arguments, saved in the run folder for ``--resume``.
    """

    def __init__(self, *args: Any, checkpoint_options: CheckpointOptions, argv: list[str], **kwargs: Any):
        super().__init__(*args, **kwargs)
        self.checkpoint_options = checkpoint_options
        self.argv = argv
        self.checkpoint: Checkpoint | None = checkpoint_for(self.trained_agent) if self.continue_training else None
        self.continues_folder = False
        self.interrupted = False
        folder = self.checkpoint.model_path.parent if self.checkpoint is not None else None
        if folder is not None and (folder / self.env_name / "args.yml").is_file():  # a model in an rl-zoo3 run folder
            self.save_path = str(folder)
            self.params_path = os.path.join(self.save_path, self.env_name)
            self.continues_folder = True

    def setup_experiment(self) -> tuple[BaseAlgorithm, dict[str, Any]] | None:
        created = outermost_missing(Path(self.save_path).absolute())
        try:
            return super().setup_experiment()
        except BaseException:
            if created is not None:
                shutil.rmtree(created, ignore_errors=True)
            raise

    def create_callbacks(self) -> None:
        super().create_callbacks()
        if not sys.stdout.isatty():  # a bar drawn into a file shows nothing
            self.callbacks = [callback for callback in self.callbacks if not isinstance(callback, ProgressBarCallback)]
        if self.verbose >= 1 and not any(isinstance(callback, ProgressBarCallback) for callback in self.callbacks):
            self.callbacks.append(ProgressLogCallback(self.n_timesteps))
        for index, callback in enumerate(self.callbacks):
            if isinstance(callback, CheckpointCallback):
                self.callbacks[index] = ResumableCheckpointCallback(
                    callback.save_freq,
                    callback.save_path,
                    callback.name_prefix,
                    save_replay_buffer=self.checkpoint_options.include_buffer,
                    keep=self.checkpoint_options.keep,
                    verbose=callback.verbose,
                )
            elif isinstance(callback, EvalCallback):
                callback.callback = self._recorder(callback.eval_env)  # rl-zoo3 sets no callback_after_eval
                step_seeded = StepSeededEvalCallback.replacing(callback, self.seed)
                if self.continues_folder:
                    continue_evaluations(step_seeded)
                self.callbacks[index] = step_seeded

    def _recorder(self, eval_env: VecEnv) -> EvalRecorderCallback:
        """The recorder of the run's evaluation CSV (a continued run's rows after the checkpoint dropped)."""
        path = run_records_path(self.save_path, self.env_name)
        if self.continues_folder:
            assert self.checkpoint is not None
            truncate_records(path, self.checkpoint.step)
            run_result_path(self.save_path, self.env_name).unlink(missing_ok=True)
        repeat = eval_env.get_attr("action_repeat")[0] if eval_env.has_attr("action_repeat") else 1
        algo = ALGOS[self.algo].__name__  # the class name, as every record writer names an algorithm
        return EvalRecorderCallback(path, algo=algo, task=self.env_name.gym_id, seed=self.seed, action_repeat=repeat)

    def create_envs(self, n_envs: int, eval_env: bool = False, no_log: bool = False) -> VecEnv:
        if self.continues_folder:
            self.monitor_kwargs = {**self.monitor_kwargs, "override_existing": False}  # append to <i>.monitor.csv
        return super().create_envs(n_envs, eval_env=eval_env, no_log=no_log)

    def _load_pretrained_agent(self, hyperparams: dict[str, Any], env: VecEnv) -> BaseAlgorithm:
        assert self.checkpoint is not None
        print(f"Continuing from {self.checkpoint.model_path} (step {self.checkpoint.step})")
        kwargs = {key: value for key, value in hyperparams.items() if key not in ("policy", "policy_kwargs")}
        return load_checkpoint(
            ALGOS[self.algo], self.checkpoint, env, seed=self.seed, tensorboard_log=self.tensorboard_log,
            verbose=self.verbose, device=self.device, **kwargs,
        )  # fmt: skip

    def _save_config(self, saved_hyperparams: dict[str, Any]) -> None:
        super()._save_config(saved_hyperparams)
        Path(self.params_path, ARGV_FILE).write_text(json.dumps(with_seed(self.argv, self.seed)))

    def learn(self, model: BaseAlgorithm) -> None:
        """rl-zoo3's ``learn`` up to ``n_timesteps`` in all; marks the run finished, or checkpoints a stopped one."""
        total = self.n_timesteps
        with noting_last_checkpoint(self.save_path, self.resume_command):
            self._learn(model)
        if model.num_timesteps >= total:
            finish_run(self.save_path, self.env_name, model.num_timesteps)
            return
        for callback in self.callbacks:
            if isinstance(callback, ResumableCheckpointCallback):
                saved = callback.save()
                print(f"Stopped at step {model.num_timesteps} of {total}: checkpoint {saved.model_path}", flush=True)

    def save_trained_model(self, model: BaseAlgorithm) -> None:
        """rl-zoo3's save; after a Ctrl-C, :class:`~sb3_ef.common.interrupt.Interrupted` saying what was kept."""
        super().save_trained_model(model)
        if self.interrupted:
            raise Interrupted(
                f"stopped at step {model.num_timesteps}, model saved to {self.save_path}/{self.env_name}.zip; "
                f"continue with `{self.resume_command}`"
            )

    @property
    def resume_command(self) -> str:
        return f"sb3-ef train --resume {self.save_path}"

    def _learn(self, model: BaseAlgorithm) -> None:
        total = self.n_timesteps
        if self.checkpoint is not None:
            if model.num_timesteps >= total:
                raise ValueError(
                    f"The run is already at step {model.num_timesteps}, which reaches its n_timesteps {total}: "
                    "pass a larger -n to train further"
                )
            env = model.get_env()
            assert env is not None  # the manager built the model with its training envs
            for callback in self.callbacks:
                if isinstance(callback, EvalCallback):
                    callback.n_calls = model.num_timesteps // env.num_envs  # evaluate at the uninterrupted run's steps
            self.n_timesteps = total - model.num_timesteps
        watched = _Watched(model, continuing=self.checkpoint is not None)
        try:
            super().learn(watched)  # type: ignore[arg-type]
        finally:
            self.n_timesteps = total
            self.interrupted = watched.interrupted
