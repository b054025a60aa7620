"""Record episodes of an sb3-ef env (motor babbling, or a saved DrQv2EF / TDMPC2EF policy) in the folder format,
with the simulator's agent masks."""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from sb3_ef.common.env_checks import FRAME_CHANNELS
from sb3_ef.ef.babbling import babble, check_babbling
from sb3_ef.offline.episodes import Episode, make_episode, write_episode

#: ``collect``'s file formats: one ``.npz`` / ``.h5`` file per episode, or a LeRobot v3.0 dataset folder.
FORMATS = ("npz", "h5", "lerobot")


def record_episode(env: Any, act: Any, seed: int | None = None, source: str = "", masks: bool = True) -> Episode:
    """Play one episode; ``act(observation) -> action``. Frames are the newest frame of each stacked observation;
    ``masks=False`` skips the agent masks (one segmentation render less per step)."""
    observation, _ = env.reset(seed=seed)
    agent_mask: Callable[[], Any] = env.unwrapped.agent_mask if masks else lambda: None
    frames, agent_masks, actions = [observation[-FRAME_CHANNELS:]], [agent_mask()], []
    done = False
    while not done:
        action = np.asarray(act(observation), dtype=np.float32)
        observation, _, terminated, truncated, _ = env.step(action)
        actions.append(action)
        frames.append(observation[-FRAME_CHANNELS:])
        agent_masks.append(agent_mask())
        done = terminated or truncated
    return make_episode(np.stack(frames), np.stack(actions), np.stack(agent_masks) if masks else None, source)


def collect(
    env_name: str,
    out_dir: str | os.PathLike,
    episodes: int = 10,
    size: int = 64,
    action_repeat: int = 2,
    mode: str = "sign",
    policy: str | None = None,
    algo: str | None = None,
    seed: int = 0,
    fast_render: bool = True,
    masks: bool | Sequence[int] = True,
    file_format: str = "npz",
    progress_bar: bool = True,
    **env_kwargs: Any,
) -> list[str]:
    """Write ``episodes`` files ``episode_00000.<npz|h5>`` to ``out_dir`` and return their paths, or with
    ``file_format="lerobot"`` a LeRobot v3.0 dataset (:class:`~sb3_ef.offline.lerobot.LeRobotWriter`: AV1 video,
    actions and agent masks in Parquet) and return ``[out_dir]``.

    NPZ / HDF5 files that already exist are kept (an interrupted collection continues where it stopped): episode
    ``i`` is reset with seed ``seed + i`` and babbles from a generator seeded with ``(seed, i)``, so it does not
    depend on the others. A LeRobot dataset is written in one go (an existing one is refused).

    :param env_name: ``dmc/<domain>-<task>``, ``metaworld/<task>`` or another registered sb3-ef env (``toy/agent-v0``).
    :param mode: babbling mode when no ``policy`` is given (``"sign"`` as in the paper, or ``"clamped_uniform"``).
    :param policy: path of a saved DrQv2EF / TDMPC2EF to act instead of babbling (its frame size and stack are used).
    :param algo: ``drqv2_ef`` or ``tdmpc2_ef`` for ``policy`` (default: tried in turn).
    :param fast_render: render without shadows and reflections (several times faster on CPU); train an RL agent
        that is to start from these frames with the same setting.
    :param env_kwargs: more ``make_env`` options, e.g. ``episode_length`` (simulator steps).
    :param masks: record agent masks for every episode (True), none (False), or the episodes of these indices
        (a LeRobot dataset has masks for every episode or none: any index records all)
        (masks are only needed to score held-out episodes; each costs a second render per step).
    """
    from sb3_ef.analysis.cli import load_ef_model

    if file_format not in FORMATS:
        raise ValueError(f"file_format must be one of {FORMATS}, got {file_format!r}")
    if isinstance(episodes, bool) or not isinstance(episodes, int) or episodes < 1:
        raise ValueError(f"episodes must be a positive number of episodes to record, got {episodes!r}")
    check_babbling(0, mode)
    rng = np.random.default_rng(seed)  # re-seeded per episode below
    if policy is not None:
        model = load_ef_model(policy, algo)
        frame_shape, frame_stack = model.frame_shape, model.observation_space.shape[0] // FRAME_CHANNELS
        act = lambda observation: model.predict(observation, deterministic=True)[0]  # noqa: E731
    else:
        frame_shape, frame_stack = (FRAME_CHANNELS, size, size), 1
        act = None
    env = _make_env(env_name, frame_shape[-1], frame_stack, action_repeat, fast_render, **env_kwargs)
    if act is None:
        act = lambda _observation: babble(rng, env.action_space.shape, mode)  # noqa: E731
    paths = []
    bar = _progress(episodes, progress_bar)
    writer = None
    try:
        for index in range(episodes):
            path = os.path.join(os.fspath(out_dir), f"episode_{index:05d}.{file_format}")
            with_masks = masks if isinstance(masks, bool) else index in masks
            if file_format == "lerobot":
                rng = np.random.default_rng([seed, index])
                source = f"{os.fspath(out_dir)} (episode {index})"
                episode = record_episode(env, act, seed=seed + index, source=source, masks=bool(masks))
                if writer is None:
                    from sb3_ef.offline.lerobot import LeRobotWriter

                    writer = LeRobotWriter(out_dir, episode.frame_shape, episode.action_dim, masks=bool(masks))
                writer.add(episode)
            elif not os.path.exists(path):
                rng = np.random.default_rng([seed, index])
                write_episode(path, record_episode(env, act, seed=seed + index, source=path, masks=with_masks))
            if file_format != "lerobot":
                paths.append(path)
            if bar is not None:
                bar.update(1)
        if writer is not None:
            paths.append(writer.close())
    finally:
        env.close()
        if bar is not None:
            bar.close()
    return paths


def _make_env(name: str, size: int, frame_stack: int, action_repeat: int, fast_render: bool, **kwargs: Any) -> Any:
    """``make_env`` for dmc/ and metaworld/ names, ``gym.make`` for other registered sb3-ef envs."""
    if name.startswith(("dmc/", "metaworld/")):
        from sb3_ef.envs import make_env

        return make_env(
            name, size=size, frame_stack=frame_stack, action_repeat=action_repeat, fast_render=fast_render, **kwargs
        )
    import gymnasium as gym

    import sb3_ef  # noqa: F401  (registers the envs)

    return gym.make(name, size=size, frame_stack=frame_stack, **kwargs)


def _progress(total: int, enabled: bool) -> Any:
    if not enabled:
        return None
    try:
        from tqdm.auto import tqdm
    except ImportError:
        return None
    return tqdm(total=total, desc="collect", unit="episode")
