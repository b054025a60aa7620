"""Ego-Foresight windows cut from an on-policy rollout, actions encoded for EF (docs/ef.md, "EF on on-policy hosts")."""

from __future__ import annotations

from collections import deque
from collections.abc import Collection, Iterator
from typing import NamedTuple, TypeAlias

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import RolloutBuffer
from stable_baselines3.common.type_aliases import RolloutBufferSamples
from torch.nn import functional as F

ENCODED_ACTION_SPACES = "Box (finite bounds), Discrete, MultiDiscrete or MultiBinary"
#: A rollout's observations: one image tensor, or a dict of them by key (``MultiInputPolicy``).
Observations: TypeAlias = "th.Tensor | dict[str, th.Tensor]"


def action_encoding_dim(space: spaces.Space) -> int:
    """Size of one action as EF reads it: a Box's components, Discrete and MultiDiscrete one-hot, MultiBinary's bits."""
    if isinstance(space, spaces.Box) and np.isfinite(space.low).all() and np.isfinite(space.high).all():
        return int(np.prod(space.shape))
    if isinstance(space, spaces.Discrete):
        return int(space.n)
    if isinstance(space, spaces.MultiDiscrete) and space.nvec.ndim == 1:
        return int(space.nvec.sum())
    if isinstance(space, spaces.MultiBinary):
        return int(np.prod(space.shape))
    raise ValueError(f"Ego-Foresight encodes actions of a {ENCODED_ACTION_SPACES} space, got {space}")


def encode_actions(actions: th.Tensor, space: spaces.Space) -> th.Tensor:
    """SB3's rollout actions ``(..., get_action_dim(space))`` as EF's float inputs ``(..., action_encoding_dim)``: a
    Box's clipped to its bounds and scaled to [-1, 1] (what the env ran), one-hots, MultiBinary's bits."""
    if isinstance(space, spaces.Box):
        low, high = (
            th.as_tensor(bound, dtype=th.float32, device=actions.device).flatten() for bound in (space.low, space.high)
        )
        return 2.0 * (th.minimum(th.maximum(actions, low), high) - low) / (high - low) - 1.0
    if isinstance(space, spaces.MultiBinary):
        return actions.float()
    sizes = [int(space.n)] if isinstance(space, spaces.Discrete) else [int(n) for n in space.nvec]  # type: ignore[attr-defined]
    one_hots = [F.one_hot(actions[..., i].long(), size) for i, size in enumerate(sizes)]
    return th.cat(one_hots, dim=-1).float()


def rollout_minibatches(
    buffer: RolloutBuffer, batch_size: int | None
) -> Iterator[tuple[np.ndarray, RolloutBufferSamples]]:
    """SB3's ``buffer.get(batch_size)``, each minibatch with its flat indices ``env * n_steps + step``: ``get`` draws
    one permutation from numpy's global generator, drawn here first from a copy of its state."""
    state = np.random.get_state()
    indices = np.random.permutation(buffer.buffer_size * buffer.n_envs)
    np.random.set_state(state)
    size = batch_size or len(indices)
    batches = [indices[start : start + size] for start in range(0, len(indices), size)]
    yield from zip(batches, buffer.get(batch_size), strict=True)


class RolloutWindow(NamedTuple):
    """EF's windows starting at some steps of a rollout (what ``ForesightLoss.prepare`` reads)."""

    observations: Observations  # (B, C * stack, h, w) uint8: the observation at t (a dict: each key's)
    future_frames: th.Tensor  # (B, H, C, h, w) uint8: the newest frame of the observations t+1 .. t+H
    future_actions: th.Tensor  # (B, H, A) float: the encoded actions t .. t+H-1
    future_mask: th.Tensor  # (B, H) bool: step t+i was taken in t's episode and its next observation is in the rollout


class RolloutWindows:
    """The EF windows of one rollout of ``n_steps`` x ``n_envs`` steps (or of several rollouts in a row, concatenated
    along the steps: :class:`RolloutRing`), cut at SB3's flat indices ``env * n_steps + step``; frames kept as uint8.

    :param observations: (n_steps, n_envs, C * stack, h, w) the rollout's observations, oldest frame first; or a
        dict of each key's (n_steps, n_envs, ...), its image keys uint8 (:class:`RolloutRing` keeps them so).
    :param actions: (n_steps, n_envs, A) the encoded actions (:func:`encode_actions`).
    :param episode_starts: (n_steps, n_envs) observation t is the first of its episode (SB3's ``episode_starts``).
    :param last_observations: (n_envs, C * stack, h, w) the observations after the last step (a dict: each key's).
    :param last_episode_starts: (n_envs,) whether those start an episode (the last step ended one).
    :param frame_channels: channels of one frame: the last ``frame_channels`` channels are the newest frame.
    :param horizon: H, the window's steps.
    :param device: where the windows are gathered.
    :param image_key: with dict observations, the key whose frames are EF's targets.
    """

    def __init__(
        self,
        observations: np.ndarray | th.Tensor | dict[str, th.Tensor],
        actions: th.Tensor,
        episode_starts: np.ndarray | th.Tensor,
        last_observations: np.ndarray | th.Tensor | dict[str, np.ndarray],
        last_episode_starts: np.ndarray | th.Tensor,
        frame_channels: int,
        horizon: int,
        device: th.device | str = "cpu",
        image_key: str | None = None,
    ):
        n_steps, n_envs = episode_starts.shape
        as_frames = lambda array: th.as_tensor(array, device=device).to(th.uint8)  # noqa: E731  (SB3 keeps float32)
        if isinstance(observations, dict):
            if image_key is None or not isinstance(last_observations, dict):
                raise ValueError(
                    "Expected an image_key and dict last_observations with dict observations, got image_key="
                    f"{image_key!r} and last_observations of type {type(last_observations).__name__}"
                )
            self.observations: Observations = {key: th.as_tensor(v, device=device) for key, v in observations.items()}
            images, last = self.observations[image_key], as_frames(last_observations[image_key])
        else:
            images = self.observations = as_frames(observations)
            last = as_frames(last_observations)
        if tuple(images.shape[:2]) != (n_steps, n_envs) or tuple(actions.shape[:2]) != (n_steps, n_envs):
            raise ValueError(
                f"Expected observations and actions of shape ({n_steps}, {n_envs}, ...), got "
                f"{tuple(images.shape)} and {tuple(actions.shape)}"
            )
        # the newest frame of observations 0 .. n_steps
        self.frames = th.cat([images[:, :, -frame_channels:], last[None, :, -frame_channels:]])
        starts = th.cat([th.as_tensor(s, device=device).bool() for s in (episode_starts, last_episode_starts[None])])
        self.continues = ~starts[1:]  # observation t+1 is in t's episode
        self.actions = actions.to(device)
        self.n_steps, self.horizon, self.device = n_steps, horizon, th.device(device)
        self.size = n_steps * n_envs

    def __call__(self, indices: np.ndarray) -> RolloutWindow:
        """The windows starting at the flat indices ``indices`` (B,) of the rollout."""
        index = th.as_tensor(indices, device=self.device)
        envs, steps = (index // self.n_steps)[:, None], index % self.n_steps
        ahead = steps[:, None] + th.arange(self.horizon, device=self.device)  # steps t .. t+H-1
        inside = ahead < self.n_steps
        ahead = ahead.clamp(max=self.n_steps - 1)
        mask = (self.continues[ahead, envs] & inside).int().cumprod(dim=1).bool()
        at = lambda values: values[steps, envs[:, 0]]  # noqa: E731
        observations = (
            {key: at(values) for key, values in self.observations.items()}
            if isinstance(self.observations, dict)
            else at(self.observations)
        )
        return RolloutWindow(observations, self.frames[ahead + 1, envs], self.actions[ahead, envs], mask)


class RolloutRing:
    """The last ``size`` rollouts (observations, encoded actions, episode starts), for windows that run from one
    rollout into the next (each rollout continues where the one before it stopped, as in SB3's ``learn``).

    :param size: rollouts kept.
    :param image_keys: with dict observations, the keys kept as uint8 (SB3's buffer keeps every key as float32);
        the others are kept as SB3 gives them. One image observation is kept as uint8.
    """

    def __init__(self, size: int, image_keys: Collection[str] = ()):
        self.rollouts: deque[tuple[Observations, th.Tensor, th.Tensor]] = deque(maxlen=size)
        self.image_keys = frozenset(image_keys)

    def add(
        self,
        observations: np.ndarray | dict[str, np.ndarray],
        actions: th.Tensor,
        episode_starts: np.ndarray,
        device: th.device | str,
    ) -> None:
        """Keep a rollout: copies of SB3's arrays, not views."""
        kept: Observations
        if isinstance(observations, dict):
            kept = {
                key: th.as_tensor(value, device=device).to(th.uint8)
                if key in self.image_keys
                else th.tensor(value, device=device)
                for key, value in observations.items()
            }
        else:
            kept = th.as_tensor(observations, device=device).to(th.uint8)
        starts = th.as_tensor(episode_starts, dtype=th.bool, device=device)  # a copy, not a view of SB3's array
        self.rollouts.append((kept, actions.to(device), starts))

    def windows(
        self,
        last_observations: np.ndarray | dict[str, np.ndarray],
        last_episode_starts: np.ndarray,
        frame_channels: int,
        horizon: int,
        image_key: str | None = None,
    ) -> RolloutWindows:
        """The windows of the rollouts held, oldest first, with the observations after the newest (arguments as
        :class:`RolloutWindows`')."""
        held, actions, starts = zip(*self.rollouts, strict=True)
        episode_starts = th.cat(starts)  # on the device the rollouts are kept on
        observations = (
            {key: th.cat([part[key] for part in held]) for key in held[0]}
            if isinstance(held[0], dict)
            else th.cat(held)
        )
        return RolloutWindows(
            observations, th.cat(actions), episode_starts, last_observations, last_episode_starts, frame_channels,
            horizon, episode_starts.device, image_key,
        )  # fmt: skip
