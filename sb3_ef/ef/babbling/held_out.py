"""Adaptive babbling's score: EF's open-loop prediction of held-out babbling episodes, against copying the frame."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np
import torch as th
from gymnasium import spaces

from sb3_ef.common.env_checks import FRAME_CHANNELS
from sb3_ef.ef.babbling.actions import babble


@dataclass
class HeldOutWindows:
    """Babbling windows recorded in an env that training never sees, with the agent masks when the env gives them
    (index 0: the newest context frame)."""

    observations: np.ndarray  # (N, 3 * stack, h, w) uint8
    actions: np.ndarray  # (N, H, action_dim) float32 in [-1, 1]
    targets: np.ndarray  # (N, H, 3, h, w) uint8
    masks: np.ndarray | None  # (N, H + 1, h, w) bool


def record_held_out_windows(
    env: gym.Env, horizon: int, steps: int, windows: int, rng: np.random.Generator, mode: str
) -> HeldOutWindows:
    """Babble ``steps`` steps in ``env`` and keep ``windows`` windows of ``horizon`` steps spread evenly over them."""
    box = env.action_space
    assert isinstance(box, spaces.Box)
    agent_mask = getattr(env.unwrapped, "agent_mask", None)
    episodes: list[tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray]]] = []
    done = True
    for _ in range(steps):
        if done:
            observation, _ = env.reset(seed=int(rng.integers(2**31)))
            episodes.append(([observation], [], [] if agent_mask is None else [agent_mask()]))
        observations, actions, masks = episodes[-1]
        action = babble(rng, box.shape, mode)
        observation, _, terminated, truncated, _ = env.step(box.low + (action + 1.0) * (box.high - box.low) / 2.0)
        observations.append(observation)
        actions.append(action)
        if agent_mask is not None:
            masks.append(agent_mask())
        done = terminated or truncated
    starts = [(e, t) for e, (_, actions, _) in enumerate(episodes) for t in range(len(actions) - horizon + 1)]
    if not starts:
        raise ValueError(
            f"Adaptive babbling needs held-out episodes longer than the EF horizon {horizon}: holdout_steps={steps} "
            f"gave episodes of at most {max(len(actions) for _, actions, _ in episodes)} steps"
        )
    picks = [starts[i] for i in np.linspace(0, len(starts) - 1, min(windows, len(starts))).round().astype(int)]
    return HeldOutWindows(
        observations=np.stack([episodes[e][0][t] for e, t in picks]),
        actions=np.stack([np.stack(episodes[e][1][t : t + horizon]) for e, t in picks]),
        targets=np.stack(
            [
                np.stack([frames[-FRAME_CHANNELS:] for frames in episodes[e][0][t + 1 : t + horizon + 1]])
                for e, t in picks
            ]
        ),
        masks=None
        if agent_mask is None
        else np.stack([np.stack(episodes[e][2][t : t + horizon + 1]) for e, t in picks]),
    )


def foresight_error_ratio(
    model: Any, windows: HeldOutWindows, agent_pixels: bool = True, batch_size: int = 16
) -> float:
    """EF's open-loop error on ``windows`` over that of copying the last frame (agent pixels if ``agent_pixels``)."""
    horizon = windows.actions.shape[1]
    sums = np.zeros((3, horizon))  # model error, copy error, pixels, per k
    policy = model.policy
    training = policy.training
    policy.set_training_mode(False)
    try:
        with th.no_grad():
            for start in range(0, len(windows.actions), batch_size):
                rows = slice(start, start + batch_size)
                observations = th.as_tensor(windows.observations[rows], device=model.device)
                predicted = model.ef.predict(
                    model.encode(observations), th.as_tensor(windows.actions[rows], device=model.device)
                ).float()
                truth = th.as_tensor(windows.targets[rows], device=model.device).float() / 255.0
                last = observations[:, None, -FRAME_CHANNELS:].float() / 255.0
                errors = [(frames - truth).pow(2).mean(dim=2) for frames in (predicted, last)]
                if windows.masks is None or not agent_pixels:
                    weight = th.ones_like(errors[0])
                else:
                    masks = th.as_tensor(windows.masks[rows], device=model.device)
                    weight = (masks[:, 1:] | masks[:, :1]).float()
                for row, value in enumerate((*(error * weight for error in errors), weight)):
                    sums[row] += value.sum(dim=(0, 2, 3)).cpu().numpy()
    finally:
        policy.set_training_mode(training)
    pixels = np.maximum(sums[2], 1.0)
    return float((sums[0] / pixels).mean() / max((sums[1] / pixels).mean(), 1e-12))
