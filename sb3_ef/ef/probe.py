"""Latent Ego-Foresight's probe decoder: frames from frozen features, to check that ``h_a`` carries the agent."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import torch as th

from sb3_ef.common.augmentation import random_shift
from sb3_ef.common.buffers import SequenceReplayBuffer
from sb3_ef.ef.foresight import LatentEgoForesight
from sb3_ef.ef.latent import MomentumTarget, draw_other_steps, stacked_observations_at


def probe_step(
    ef: LatentEgoForesight,
    optimizer: th.optim.Optimizer,
    h: th.Tensor,
    future_actions: th.Tensor,
    steps: th.Tensor,
    target: th.Tensor,
    valid: th.Tensor | None = None,
    skip: th.Tensor | None = None,
) -> th.Tensor:
    """One probe step of ``optimizer`` (``ef.decoder`` only), leaving no ``.grad`` for the host's optimisers."""
    parameters = list(ef.decoder.parameters())
    owned = {id(p) for p in parameters}
    stepped = [p for group in optimizer.param_groups for p in group["params"]]
    if not stepped or any(id(p) not in owned for p in stepped):
        raise ValueError("probe_step's optimizer must hold ef.decoder's parameters only")
    loss = ef.probe_loss(h, future_actions, steps, target, valid, skip)
    for parameter, grad in zip(parameters, th.autograd.grad(loss, parameters), strict=True):
        parameter.grad = grad
    optimizer.step()
    for parameter in parameters:
        parameter.grad = None
    ef.probe_steps += 1
    return loss.detach()


def fit_probe(
    model: Any,
    steps: int = 2000,
    batch_size: int = 32,
    learning_rate: float = 1e-3,
    pad: int = 0,
    seed: int = 0,
    replay_buffer: Any = None,
) -> list[float]:
    """Train the probe decoder of ``model.ef`` on its replay buffer, leaving the rest of the model as it was.

    :param model: a trained EF host built with ``ef_kwargs=dict(target="latent")``.
    :param steps: probe updates.
    :param batch_size: windows per update.
    :param learning_rate: the probe's Adam learning rate.
    :param pad: random shift of the context and frame t+k (0: the frames as recorded, as analysis reads them).
    :param seed: seeds the windows, k and the shifts.
    :param replay_buffer: a :class:`~sb3_ef.common.buffers.SequenceReplayBuffer` to read instead of the model's.
    """
    ef = getattr(model, "ef", None)
    if not isinstance(ef, LatentEgoForesight):
        raise ValueError(
            f"fit_probe needs a model with latent Ego-Foresight (ef_kwargs=dict(target='latent')), got "
            f"{type(model).__name__} with ef={type(ef).__name__}{'' if ef is None else ' target=' + repr(ef.target)}"
        )
    for name, value in (("steps", steps), ("batch_size", batch_size)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ValueError(f"{name} must be a positive int, got {value!r}")
    buffer = replay_buffer if replay_buffer is not None else getattr(model, "replay_buffer", None)
    if not isinstance(buffer, SequenceReplayBuffer):
        raise ValueError(
            f"fit_probe samples EF windows from a SequenceReplayBuffer, got {type(buffer).__name__}: train the "
            "model first or pass one as replay_buffer"
        )
    if buffer.size() == 0:
        raise ValueError("fit_probe samples a replay buffer with transitions, got an empty one: train the model first")
    sampler = buffer.side_sampler(seed)
    optimizer = th.optim.Adam(ef.decoder.parameters(), lr=learning_rate)
    generator = th.Generator(device=buffer.device).manual_seed(seed)
    policy = getattr(model, "policy", None)
    was_training = policy.training if policy is not None else None
    if policy is not None:
        policy.set_training_mode(False)
    ef.decoder.train(True)  # batch statistics while fitting, running ones for analysis
    losses = []
    try:
        for _ in range(steps):
            batch = sampler.sample(batch_size, buffer.device, None)
            k = ef.draw_steps(batch.future_mask, generator=generator)
            rows = th.arange(k.shape[0], device=k.device)
            context, frame = random_shift(
                batch.observations, batch.future_frames[rows, k - 1], pad=pad, generator=generator
            )
            with th.no_grad():
                h = model.encode(context)
            valid = batch.future_mask[rows, k - 1]
            losses.append(probe_step(ef, optimizer, h, batch.future_actions, k, frame, valid))
    finally:
        ef.decoder.eval()
        if policy is not None:
            policy.set_training_mode(bool(was_training))
    return [float(loss) for loss in th.stack(losses)]


def latent_window_losses(
    ef: LatentEgoForesight,
    target: MomentumTarget,
    features: Callable[[th.Tensor], tuple[th.Tensor, th.Tensor | None]],
    observations: th.Tensor,
    frames: th.Tensor,
    actions: th.Tensor,
    steps: th.Tensor,
    pad: int = 0,
) -> tuple[th.Tensor, th.Tensor]:
    """Latent EF's loss and its probe's loss on a batch of full windows (offline pretraining).

    :param features: ``(h, skip)`` of uint8 stacked observations (the offline model's ``features``).
    :param frames: (B, H, 3, h, w) frames t+1 .. t+H; ``steps``: (B,) k; ``pad``: random shift, 0: none.
    """
    rows = th.arange(steps.shape[0], device=steps.device)
    valid = th.ones(steps.shape[0], ef.horizon, dtype=th.bool, device=steps.device)
    others = draw_other_steps(valid, steps, ef.horizon)
    future = [stacked_observations_at(observations, frames, steps)]
    if others is not None:
        future.append(stacked_observations_at(observations, frames, others))
    frame = frames[rows, steps - 1]
    candidates = th.cat(future)
    if pad:
        observations, frame = random_shift(observations, frame, pad=pad)
        (candidates,) = random_shift(candidates, pad=pad)
    h, skip = features(observations)
    latent = ef.loss(h, actions, steps, target(candidates))
    return latent, ef.probe_loss(h, actions, steps, frame, skip=skip)
