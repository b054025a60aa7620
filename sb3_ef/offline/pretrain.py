"""Offline pretraining of an encoder + Ego-Foresight on (frames, actions) episodes, as in the paper's BAIR
experiment: held-out episodes, TensorBoard scalars and image grids, resumable checkpoints and a progress bar."""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from typing import Any, TypeVar

import torch as th

from sb3_ef.analysis.prediction import frame_grid, to_uint8_frames
from sb3_ef.common.augmentation import random_shift
from sb3_ef.offline.episodes import Episode, EpisodeError
from sb3_ef.offline.evaluate import evaluate, predict_windows
from sb3_ef.offline.model import OfflineEF, OfflineEFConfig, load_pretrained
from sb3_ef.offline.readers import EpisodeDataset, open_dataset
from sb3_ef.offline.streaming import EpisodeList, check_like, window_batches
from sb3_ef.offline.windows import Windows, cut_windows

CHECKPOINT = "checkpoint.pt"
MODEL = "model.pt"
METRICS = "metrics.json"
T = TypeVar("T")


def split_holdout(episodes: Sequence[T], holdout: int | float) -> tuple[list[T], list[T]]:
    """The last ``holdout`` episodes (a count, or a fraction when < 1) are held out; at least one stays for training."""
    count = round(holdout * len(episodes)) if isinstance(holdout, float) and holdout < 1 else int(holdout)
    if not 0 <= count < len(episodes):
        raise ValueError(f"holdout must leave at least one of {len(episodes)} episodes for training, got {holdout}")
    return list(episodes[: len(episodes) - count]), list(episodes[len(episodes) - count :])


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
    resume: bool = True,
    overwrite: bool = False,
    progress_bar: bool = True,
    tensorboard: bool = True,
    cache_mb: float = 1024,
    workers: int = 0,
) -> tuple[OfflineEF, dict[str, Any]]:
    """Train encoder + EF to predict frame t + k from ``context`` frames and k actions (k drawn in 1..``horizon``).

    Writes to ``out_dir``: ``checkpoint.pt`` every ``checkpoint_every`` steps (training restarts from it when
    ``resume``), ``model.pt`` at the end (load with :func:`~sb3_ef.offline.model.load_pretrained`), ``metrics.json``
    with the held-out scores of :func:`~sb3_ef.offline.evaluate.evaluate`, and TensorBoard logs under ``tb/``.

    :param dataset: a source for :func:`~sb3_ef.offline.readers.open_dataset`, a reader, or loaded episodes.
    :param encoder: ``"dcgan-unet"`` (64x64, U-Net skips), ``"drqv2"`` or ``"tdmpc2"`` (64x64).
    :param shift_pad: random-shift augmentation of context and target together (DrQ-v2's is 4), 0 for none.
    :param saliency_windows: held-out windows whose h_a saliency is scored at the end (each costs one backward
        pass per 4x4 patch of the frame).
    :param holdout: held-out episodes (count, or fraction when < 1), the last ones of the dataset.
    :param resume: continue from ``checkpoint.pt`` of an unfinished (or shorter) run in ``out_dir``.
    :param overwrite: train again over a finished run (``model.pt`` at ``steps`` or more); refused otherwise.
    :param cache_mb: memory for decoded training episodes: a dataset that does not fit is streamed
        (:mod:`sb3_ef.offline.streaming`); held-out episodes are loaded whole.
    :param workers: ``DataLoader`` worker processes decoding windows (0: in this process).
    :return: the trained model (eval mode) and the final held-out scores.
    """
    if not cache_mb > 0 or workers < 0:
        raise ValueError(f"Expected cache_mb > 0 and workers >= 0, got cache_mb={cache_mb}, workers={workers}")
    th.manual_seed(seed)
    _refuse_finished_run(out_dir, steps, resume, overwrite)
    if isinstance(dataset, EpisodeDataset):
        reader = dataset
    elif isinstance(dataset, list):
        reader = EpisodeList(dataset)
    else:
        reader = open_dataset(dataset, context + horizon)
    reader.min_frames = context + horizon
    lengths = reader.lengths()
    short = [i for i, length in enumerate(lengths) if length < context + horizon]
    if short:
        reader[short[0]]  # raises the reader's EpisodeError naming the file and episode
    if not lengths:
        raise EpisodeError("The dataset holds no episodes")
    train_indices, held_out_indices = split_holdout(range(len(reader)), holdout)
    first = reader[train_indices[0]]
    held_out = [check_like(reader[i], first) for i in held_out_indices]
    config = OfflineEFConfig(
        encoder, first.frame_shape, first.action_dim, context, horizon, agent_dim, encoder_kwargs or {}, ef_kwargs or {}
    )
    os.makedirs(out_dir, exist_ok=True)
    checkpoint_path = os.path.join(out_dir, CHECKPOINT)
    start = 0
    if resume and os.path.isfile(checkpoint_path):
        model, checkpoint = load_pretrained(checkpoint_path, device)
        if model.config != config:
            raise ValueError(
                f"{checkpoint_path} was trained with {model.config}, not {config}: use another out_dir or resume=False"
            )
        start = checkpoint["step"]
        if start > steps:
            raise ValueError(f"{checkpoint_path} is already at step {start}, beyond steps={steps}")
    else:
        model, checkpoint = OfflineEF(config).to(device), None
    model.train()
    optimizer = th.optim.Adam(model.parameters(), lr=learning_rate)
    batches = window_batches(
        reader,
        train_indices,
        [lengths[i] for i in train_indices],
        context,
        horizon,
        batch_size,
        cache_mb,
        workers,
        seed + start,
    )
    if checkpoint is not None:
        optimizer.load_state_dict(checkpoint["optimizer"])
    writer = _writer(os.path.join(out_dir, "tb")) if tensorboard else None
    bar = _progress(steps, start, progress_bar)
    for step in range(start, steps):
        batch = _to(next(batches), device)
        ef_steps = model.ef.draw_steps(th.ones(batch_size, horizon, dtype=th.bool, device=device))
        target = batch.frames[th.arange(batch_size, device=device), ef_steps - 1]
        observations = batch.observations
        if shift_pad:
            observations, target = random_shift(observations, target, pad=shift_pad)
        h, skip = model.features(observations)
        loss = model.ef.loss(h, batch.actions, ef_steps, target, skip=skip)
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        done = step + 1
        if bar is not None:
            bar.update(1)
            bar.set_postfix(loss=f"{loss.item():.1f}")
        if writer is not None and (done % 50 == 0 or done == steps):
            writer.add_scalar("train/ef_loss", loss.item(), done)
        if held_out and writer is not None and done % eval_every == 0 and done < steps:
            _log_evaluation(
                writer, model, held_out, done, evaluate(model, held_out, saliency_windows=min(8, saliency_windows))
            )
            model.train()
        if done % checkpoint_every == 0 or done == steps:
            th.save(model.checkpoint(step=done, optimizer=optimizer.state_dict()), checkpoint_path)
    batches.close()  # stops the DataLoader workers, if any
    if bar is not None:
        bar.close()
    model.eval()
    scores = evaluate(model, held_out, saliency_windows=saliency_windows, progress=progress_bar) if held_out else {}
    if held_out and writer is not None:
        _log_evaluation(writer, model, held_out, steps, scores)
    th.save(model.checkpoint(step=steps), os.path.join(out_dir, MODEL))
    with open(os.path.join(out_dir, METRICS), "w") as file:
        json.dump(
            {"steps": steps, "train_episodes": len(train_indices), "held_out_episodes": len(held_out), **scores},
            file,
            indent=2,
        )
    if writer is not None:
        writer.close()
    return model, scores


def _refuse_finished_run(out_dir: str | os.PathLike, steps: int, resume: bool, overwrite: bool) -> None:
    """A finished run (``model.pt`` at ``steps`` or beyond) is kept unless ``overwrite``: only a resumed run with
    more steps continues it."""
    model_path = os.path.join(out_dir, MODEL)
    if overwrite or not os.path.isfile(model_path):
        return
    done = th.load(model_path, map_location="cpu", weights_only=False).get("step", 0)
    if resume and done < steps:
        return
    raise FileExistsError(
        f"{model_path} holds a finished run of {done} steps: pass overwrite=True (sb3-ef pretrain --overwrite) to "
        f"train again from scratch into {os.fspath(out_dir)}, a larger steps to continue it, or another folder"
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


def _progress(total: int, initial: int, enabled: bool) -> Any:
    if not enabled:
        return None
    try:
        from tqdm.auto import tqdm
    except ImportError:
        return None
    return tqdm(total=total, initial=initial, desc="pretrain", unit="step")
