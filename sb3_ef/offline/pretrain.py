"""Offline pretraining of an encoder + Ego-Foresight on (frames, actions) episodes: see docs/offline.md."""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any, TypeVar

import torch as th

from sb3_ef.analysis.prediction import frame_grid, to_uint8_frames
from sb3_ef.common.augmentation import random_shift
from sb3_ef.common.files import write_atomically, write_text_atomically
from sb3_ef.common.interrupt import Interrupted, sigint_deferred
from sb3_ef.common.precision import autocast, check_precision
from sb3_ef.ef.probe import latent_window_losses
from sb3_ef.offline.dataset import EpisodeDataset
from sb3_ef.offline.episodes import Episode, EpisodeError
from sb3_ef.offline.evaluate import evaluate, predict_windows
from sb3_ef.offline.model import OfflineEF, OfflineEFConfig, load_pretrained, read_checkpoint
from sb3_ef.offline.progress import make_progress_bar
from sb3_ef.offline.readers import open_dataset
from sb3_ef.offline.streaming import EpisodeList, window_batches
from sb3_ef.offline.windows import Windows, cut_windows

CHECKPOINT = "checkpoint.pt"
MODEL = "model.pt"
METRICS = "metrics.json"
#: ``pretrain``'s arguments and the ``sb3-ef pretrain`` options that set them, for the messages.
_DASHED = (
    "steps batch_size shift_pad holdout eval_every checkpoint_every encoder context horizon agent_dim cache_mb workers "
    "precision"
)
OPTIONS = {name: f"--{name.replace('_', '-')}" for name in (*_DASHED.split(), "encoder_kwargs", "ef_kwargs")}
OPTIONS.update(learning_rate="--lr", frame_shape="the dataset's frames", action_dim="the dataset's actions")
#: The training settings a resumed run shares with the checkpoint it continues (recorded in every checkpoint).
RESUMED_SETTINGS = ("learning_rate", "batch_size", "shift_pad", "holdout", "precision")
T = TypeVar("T")


def split_holdout(episodes: Sequence[T], holdout: int | float) -> tuple[list[T], list[T]]:
    """The last ``holdout`` episodes (a count, or a fraction when < 1) are held out; at least one stays for training."""
    count = round(holdout * len(episodes)) if isinstance(holdout, float) and holdout < 1 else int(holdout)
    if not 0 <= count < len(episodes):
        raise ValueError(f"holdout must leave at least one of {len(episodes)} episodes for training, got {holdout}")
    return list(episodes[: len(episodes) - count]), list(episodes[len(episodes) - count :])


@dataclass
class _Run:
    """What the training loop needs, besides the batches. ``settings``: ``pretrain``'s training arguments."""

    out_dir: str
    model: OfflineEF
    optimizer: th.optim.Optimizer
    settings: dict[str, Any]
    held_out: list[Episode]
    device: str
    writer: Any

    @property
    def steps(self) -> int:
        return self.settings["steps"]

    def save(self, name: str, step: int, with_optimizer: bool = True) -> str:
        """The model (with the optimiser and the settings) as ``out_dir/name``, written atomically."""
        extra = {"optimizer": self.optimizer.state_dict()} if with_optimizer else {}
        training = {name: self.settings[name] for name in RESUMED_SETTINGS}
        checkpoint = self.model.checkpoint(step=step, training=training, **extra)
        path = os.path.join(self.out_dir, name)
        with sigint_deferred():  # torch turns an interrupt inside its writer into a RuntimeError
            try:
                write_atomically(path, lambda file: th.save(checkpoint, file))
            except RuntimeError as error:  # torch's zip writer reports a failed write (a full disk) this way
                free = shutil.disk_usage(self.out_dir).free
                raise OSError(f"Could not write {path} ({free} bytes free on its disk): {error}") from None
        return path


def pretrain(
    dataset: str | os.PathLike | EpisodeDataset | list[Episode],
    out_dir: str | os.PathLike,
    encoder: str = "dcgan-unet",
    context: int = 3,
    horizon: int = 10,
    agent_dim: int = 32,
    steps: int = 10_000,
    batch_size: int = 32,
    learning_rate: float = 1e-3,
    shift_pad: int = 0,
    holdout: int | float = 0.1,
    eval_every: int = 1000,
    checkpoint_every: int = 500,
    saliency_windows: int = 32,
    encoder_kwargs: dict[str, Any] | None = None,
    ef_kwargs: dict[str, Any] | None = None,
    seed: int = 0,
    device: str = "cpu",
    precision: str = "fp32",
    resume: bool = True,
    overwrite: bool = False,
    progress_bar: bool = True,
    tensorboard: bool = True,
    cache_mb: float = 1024,
    workers: int = 0,
) -> tuple[OfflineEF, dict[str, Any]]:
    """Train encoder + EF to predict frame t + k from ``context`` frames and k actions (k in 1..``horizon``),
    writing ``checkpoint.pt``, ``model.pt``, ``metrics.json`` and ``tb/`` into ``out_dir`` (see docs/offline.md).

    :param dataset: a source for :func:`~sb3_ef.offline.readers.open_dataset`, a reader, or loaded episodes.
    :param encoder: ``"dcgan-unet"`` (U-Net skips), ``"drqv2"`` or ``"tdmpc2"``, all on 64x64 frames.
    :param shift_pad: random-shift pad of context and target together (DrQ-v2's is 4), 0 for none.
    :param saliency_windows: held-out windows whose h_a saliency is scored at the end (slow: a backward per patch).
    :param holdout: held-out episodes (count, or fraction when < 1), the last ones of the dataset.
    :param precision: ``"fp32"`` or ``"bf16"`` (bfloat16 mixed precision of the updates, docs/precision.md).
    :param resume: continue from ``checkpoint.pt`` of an unfinished (or shorter) run in ``out_dir``.
    :param overwrite: train again over a finished run (``model.pt`` at ``steps`` or more); refused otherwise.
    :param cache_mb: memory for decoded training episodes; a dataset that does not fit is streamed.
    :param workers: ``DataLoader`` worker processes decoding windows (0: in this process).
    :return: the trained model (eval mode) and the final held-out scores.
    """
    settings: dict[str, Any] = {"steps": steps, "batch_size": batch_size, "learning_rate": learning_rate}
    settings.update(shift_pad=shift_pad, holdout=holdout, eval_every=eval_every, checkpoint_every=checkpoint_every)
    settings["precision"] = precision
    _check_settings({**settings, "saliency_windows": saliency_windows, "cache_mb": cache_mb, "workers": workers})
    check_precision(precision, device)
    th.manual_seed(seed)
    out_dir = os.fspath(out_dir)
    _refuse_finished_run(out_dir, steps, resume, overwrite)
    reader = _reader(dataset, context + horizon)
    lengths = reader.lengths()
    train_indices, held_out = _split(reader, lengths, holdout)
    first = reader[train_indices[0]]
    config = OfflineEFConfig(
        encoder, first.frame_shape, first.action_dim, context, horizon, agent_dim, encoder_kwargs or {}, ef_kwargs or {}
    )
    os.makedirs(out_dir, exist_ok=True)
    model, optimizer, start = _start(out_dir, config, settings, resume, device)
    writer = _writer(os.path.join(out_dir, "tb")) if tensorboard else None
    run = _Run(out_dir, model, optimizer, {**settings, "saliency_windows": saliency_windows}, held_out, device, writer)
    train_lengths = [lengths[i] for i in train_indices]
    batches = window_batches(
        reader, train_indices, train_lengths, context, horizon, batch_size, cache_mb, workers, seed + start
    )
    try:
        _train(run, batches, start, progress_bar)
        scores = _finish(run, len(train_indices), progress_bar)
    finally:
        batches.close()  # stops the DataLoader workers, if any
        if writer is not None:
            writer.close()
    return model, scores


def _check_settings(values: dict[str, Any]) -> None:
    rules: dict[str, tuple[str, int | None]] = {
        "learning_rate": ("a number > 0", None),
        "cache_mb": ("a number > 0", None),
    }
    rules.update(dict.fromkeys(("steps", "batch_size", "eval_every", "checkpoint_every"), ("an integer >= 1", 1)))
    rules.update(dict.fromkeys(("shift_pad", "saliency_windows", "workers"), ("an integer >= 0", 0)))
    problems = [
        f"{name}{f' ({OPTIONS[name]})' if name in OPTIONS else ''} must be {expected}, got {values[name]!r}"
        for name, (expected, least) in rules.items()
        if not (_is_int(values[name], least) if least is not None else _is_positive(values[name]))
    ]
    if problems:
        raise ValueError("; ".join(problems))


def _is_positive(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and value > 0


def _is_int(value: Any, least: int) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= least


def _reader(dataset: str | os.PathLike | EpisodeDataset | list[Episode], min_frames: int) -> EpisodeDataset:
    if isinstance(dataset, EpisodeDataset):
        reader = dataset
    elif isinstance(dataset, list):
        reader = EpisodeList(dataset)
    else:
        reader = open_dataset(dataset, min_frames)
    reader.min_frames = min_frames
    return reader


def _split(reader: EpisodeDataset, lengths: list[int], holdout: int | float) -> tuple[list[int], list[Episode]]:
    """Training episode indices and the held-out episodes (read whole), after the length checks."""
    if not lengths:
        raise EpisodeError("The dataset holds no episodes")
    short = [i for i, length in enumerate(lengths) if length < reader.min_frames]
    if short:
        reader[short[0]]  # raises the reader's EpisodeError naming the file and episode
    train_indices, held_out_indices = split_holdout(range(len(reader)), holdout)
    return train_indices, [reader[i] for i in held_out_indices]


def _start(
    out_dir: str, config: OfflineEFConfig, settings: dict[str, Any], resume: bool, device: str
) -> tuple[OfflineEF, th.optim.Optimizer, int]:
    """A new model and optimiser, or those of ``out_dir/checkpoint.pt`` when resuming, and the step to start at."""
    path = os.path.join(out_dir, CHECKPOINT)
    if not (resume and os.path.isfile(path)):
        model = OfflineEF(config).to(device)
        return model, th.optim.Adam(model.parameters(), lr=settings["learning_rate"]), 0
    start_over = "pass resume=False (sb3-ef pretrain --no-resume) to start over, replacing it"
    try:
        model, checkpoint = load_pretrained(path, device)
    except ValueError as error:
        raise ValueError(f"{error}: {start_over}") from None
    requested = {**vars(config), **{name: settings[name] for name in RESUMED_SETTINGS}}
    # A checkpoint written before the precision option trained in float32.
    recorded = {**vars(model.config), "precision": "fp32", **checkpoint.get("training", requested)}
    differences = [
        f"{name} {recorded[name]!r} ({OPTIONS[name]}), not {requested[name]!r}"
        for name in requested
        if _normalised(recorded[name]) != _normalised(requested[name])
    ]
    if differences:
        raise ValueError(
            f"{path} was trained with {'; '.join(differences)}: resume with the same settings, {start_over}, or "
            "train into another folder"
        )
    if checkpoint["step"] > settings["steps"]:
        raise ValueError(f"{path} is already at step {checkpoint['step']}, beyond steps={settings['steps']} (--steps)")
    model.train()
    optimizer = th.optim.Adam(model.parameters(), lr=settings["learning_rate"])
    optimizer.load_state_dict(checkpoint["optimizer"])
    return model, optimizer, int(checkpoint["step"])


def _normalised(value: Any) -> Any:
    """Tuples and lists alike (a configuration read back from a checkpoint holds lists)."""
    if isinstance(value, (list, tuple)):
        return [_normalised(item) for item in value]
    if isinstance(value, dict):
        return {key: _normalised(item) for key, item in value.items()}
    return value


def _train(run: _Run, batches: Iterator[Windows], start: int, show_progress: bool) -> None:
    """Updates ``start`` .. ``run.steps`` with logging, evaluations and checkpoints (one saved on Ctrl-C)."""
    model, done = run.model, start
    bar = make_progress_bar(run.steps, "pretrain", "step", show_progress, initial=start)
    model.train()
    try:
        for step in range(start, run.steps):
            batch = next(batches)
            with sigint_deferred(), autocast(run.settings["precision"], th.device(run.device)):
                loss = _update(run, batch)  # Ctrl-C lands between updates, never inside one
                done = step + 1
            bar.update(1)
            bar.set_postfix(loss=f"{loss:.1f}")
            if run.writer is not None and (done % 50 == 0 or done == run.steps):
                run.writer.add_scalar("train/ef_loss", loss, done)
            if run.held_out and run.writer is not None and done % run.settings["eval_every"] == 0 and done < run.steps:
                scores = evaluate(model, run.held_out, saliency_windows=min(8, run.settings["saliency_windows"]))
                _log_evaluation(run.writer, model, run.held_out, done, scores)
                model.train()
            if done % run.settings["checkpoint_every"] == 0 or done == run.steps:
                run.save(CHECKPOINT, done)
    except KeyboardInterrupt:
        bar.close()
        if done == start:
            raise Interrupted(f"stopped at step {done} of {run.steps}, before another update finished") from None
        path = run.save(CHECKPOINT, done)
        raise Interrupted(f"stopped at step {done} of {run.steps}; {path} saved: rerun the command to go on") from None
    bar.close()


def _update(run: _Run, batch: Windows) -> float:
    model, device = run.model, run.device
    batch = _to(batch, device)
    batch_size, horizon = batch.actions.shape[:2]
    ef_steps = model.ef.draw_steps(th.ones(batch_size, horizon, dtype=th.bool, device=device))
    if model.target_encoder is not None:  # latent EF, and its probe decoder on detached features (docs/ef.md)
        latent, probe = latent_window_losses(
            model.ef, model.target_encoder, model.features, batch.observations, batch.frames, batch.actions, ef_steps,
            run.settings["shift_pad"],
        )  # fmt: skip
        loss = latent + probe
        model.ef.probe_steps += 1
    else:
        target = batch.frames[th.arange(batch_size, device=device), ef_steps - 1]
        observations = batch.observations
        if run.settings["shift_pad"]:
            observations, target = random_shift(observations, target, pad=run.settings["shift_pad"])
        h, skip = model.features(observations)
        loss = model.ef.loss(h, batch.actions, ef_steps, target, skip=skip)
    run.optimizer.zero_grad(set_to_none=True)
    loss.backward()
    run.optimizer.step()
    if model.target_encoder is not None:
        model.target_encoder.update(model.encoder, model.ef.head.projection)
    return loss.item()


def _finish(run: _Run, train_episodes: int, show_progress: bool) -> dict[str, Any]:
    """The final held-out scores, ``model.pt`` and ``metrics.json``."""
    model, held_out = run.model, run.held_out
    model.eval()
    scores: dict[str, Any] = {}
    try:
        if held_out:
            saliency_windows = run.settings["saliency_windows"]
            scores = evaluate(model, held_out, saliency_windows=saliency_windows, progress=show_progress)
    except KeyboardInterrupt:
        checkpoint = os.path.join(run.out_dir, CHECKPOINT)
        raise Interrupted(
            f"stopped in the final evaluation; {checkpoint} holds all {run.steps} steps: rerun the command to "
            "evaluate and write model.pt"
        ) from None
    if held_out and run.writer is not None:
        _log_evaluation(run.writer, model, held_out, run.steps, scores)
    run.save(MODEL, run.steps, with_optimizer=False)
    metrics = {"steps": run.steps, "train_episodes": train_episodes, "held_out_episodes": len(held_out), **scores}
    with sigint_deferred():
        write_text_atomically(os.path.join(run.out_dir, METRICS), json.dumps(metrics, indent=2))
    return scores


def _refuse_finished_run(out_dir: str, steps: int, resume: bool, overwrite: bool) -> None:
    """Keep a finished run (``model.pt`` at ``steps`` or beyond) unless ``overwrite`` or resumed with more steps."""
    model_path = os.path.join(out_dir, MODEL)
    if overwrite or not os.path.isfile(model_path):
        return
    try:
        done = read_checkpoint(model_path).get("step", 0)
    except ValueError as error:
        raise ValueError(
            f"{error}: pass overwrite=True (sb3-ef pretrain --overwrite) to train into {out_dir} again"
        ) from None
    if resume and done < steps:
        return
    raise FileExistsError(
        f"{model_path} holds a finished run of {done} steps: pass overwrite=True (sb3-ef pretrain --overwrite) to "
        f"train again from scratch into {out_dir}, a larger steps to continue it, or another folder"
    )


def _to(windows: Windows, device: th.device | str) -> Windows:
    masks = windows.masks.to(device) if windows.masks is not None else None
    return Windows(windows.observations.to(device), windows.actions.to(device), windows.frames.to(device), masks)


def _log_evaluation(writer: Any, model: OfflineEF, held_out: list[Episode], step: int, scores: dict) -> None:
    """Held-out scalars and one image grid: context frames, predicted frames t+1..t+H, true frames."""
    for name, value in scores.items():
        if isinstance(value, float):
            writer.add_scalar(f"eval/{name}", value, step)
    context, horizon = model.config.context, model.config.horizon
    windows = cut_windows(held_out, [(0, context - 1)], context, horizon, next(model.parameters()).device)
    predicted = to_uint8_frames(predict_windows(model, windows)[0])
    truth = windows.frames[0].permute(0, 2, 3, 1).cpu().numpy()
    context_frames = windows.observations[0].reshape(context, 3, *truth.shape[1:3]).permute(0, 2, 3, 1).cpu().numpy()
    grid = frame_grid([context_frames, predicted, truth])
    writer.add_image("eval/context_predicted_true", grid, step, dataformats="HWC")


def _writer(log_dir: str) -> Any:
    from torch.utils.tensorboard import SummaryWriter

    return SummaryWriter(log_dir)
