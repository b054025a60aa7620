"""Record episodes of an sb3-ef env (babbling or a saved policy) with agent masks; see docs/offline.md."""

from __future__ import annotations

import glob
import json
import os
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sb3_ef.common.acting import EpisodeActor
from sb3_ef.common.env_checks import FRAME_CHANNELS
from sb3_ef.common.files import refuse_files_in, write_text_atomically
from sb3_ef.common.interrupt import Interrupted, sigint_deferred
from sb3_ef.ef.babbling import babble, check_babbling
from sb3_ef.offline.episodes import (
    HDF5_SUFFIXES,
    NPZ_SUFFIXES,
    Episode,
    EpisodeError,
    make_episode,
    read_episode_file,
    write_episode,
)
from sb3_ef.offline.progress import make_progress_bar

FORMATS = ("npz", "h5", "lerobot")
RECORD = "sb3_ef_collect.json"
#: The ``sb3-ef collect`` options that set ``collect``'s recorded arguments, where not ``--<argument>``.
OPTIONS = {
    "env_name": "ENV",
    "fast_render": "--slow-render",
    "masks": "--no-masks",
    "file_format": "--format",
    "env_kwargs": "env_kwargs",
}


def record_episode(env: Any, act: Any, seed: int | None = None, source: str = "", masks: bool = True) -> Episode:
    """Play one episode with ``act(observation) -> action``, keeping each observation's newest frame (and mask)."""
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


class _Recorder:
    """The env and the actor (babbling, or the saved ``policy``) of a collection."""

    def __init__(self, settings: dict[str, Any], env_kwargs: dict[str, Any]):
        from sb3_ef.analysis.cli import load_ef_model

        self.seed, self.mode = settings["seed"], settings["mode"]
        self.rng = np.random.default_rng(self.seed)
        size, frame_stack, self.actor = settings["size"], 1, None
        if settings["policy"] is not None:
            model = load_ef_model(settings["policy"], settings["algo"])
            size = model.frame_shape[-1]
            frame_stack = model.observation_space.shape[0] // FRAME_CHANNELS
            self.actor = EpisodeActor(model)
        self.env = _make_env(
            settings["env_name"], size, frame_stack, settings["action_repeat"], settings["fast_render"], **env_kwargs
        )
        self.frame_shape = (FRAME_CHANNELS, size, size)
        self.action_dim = int(np.prod(self.env.action_space.shape))

    def _act(self, observation: np.ndarray) -> np.ndarray:
        if self.actor is not None:
            return self.actor(observation)
        return babble(self.rng, self.env.action_space.shape, self.mode)

    def episode(self, index: int, source: str, masks: bool) -> Episode:
        self.rng = np.random.default_rng([self.seed, index])
        if self.actor is not None:
            self.actor.reset()
        return record_episode(self.env, self._act, seed=self.seed + index, source=source, masks=masks)


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
    """Record ``episodes`` into ``out_dir`` and return the files (or ``[out_dir]`` for LeRobot); reruns resume.

    :param env_name: ``dmc/<domain>-<task>``, ``metaworld/<task>`` or another registered sb3-ef env.
    :param mode: babbling mode when no ``policy`` is given (``"sign"`` as in the paper, or ``"clamped_uniform"``).
    :param policy: a saved DrQv2EF / TDMPC2EF (``algo``: ``drqv2_ef`` or ``tdmpc2_ef``, else both tried) to act.
    :param fast_render: render without shadows and reflections (faster on CPU; train on the same setting).
    :param env_kwargs: more ``make_env`` options, e.g. ``episode_length`` (simulator steps).
    :param masks: agent masks for every episode, none, or the episodes of these indices (LeRobot: any index, all).
    """
    if file_format not in FORMATS:
        raise ValueError(f"file_format must be one of {FORMATS}, got {file_format!r}")
    if isinstance(episodes, bool) or not isinstance(episodes, int) or episodes < 1:
        raise ValueError(f"episodes must be a positive number of episodes to record, got {episodes!r}")
    check_babbling(0, mode)
    out_dir = os.fspath(out_dir)
    settings = {"env_name": env_name, "size": size, "action_repeat": action_repeat, "mode": mode, "policy": policy}
    settings.update(algo=algo, seed=seed, fast_render=fast_render, file_format=file_format, env_kwargs=env_kwargs)
    settings["masks"] = masks if isinstance(masks, bool) else sorted(int(index) for index in masks)
    settings = json.loads(json.dumps(settings, default=repr))  # as recorded: tuples become lists
    _check_folder(out_dir, settings)
    recorder = _Recorder(settings, env_kwargs)
    bar = make_progress_bar(episodes, "collect", "episode", progress_bar)
    try:
        if file_format == "lerobot":
            return [_collect_lerobot(recorder, out_dir, settings, episodes, bar)]
        return _collect_files(recorder, out_dir, settings, episodes, masks, bar)
    finally:
        recorder.env.close()
        bar.close()


def _check_folder(out_dir: str, settings: dict[str, Any]) -> None:
    """Refuse a folder collected with other settings, or (for a LeRobot dataset) holding anything else."""
    path = os.path.join(out_dir, RECORD)
    if os.path.isfile(path):
        with open(path) as file:
            recorded = json.load(file)
        ignored = {"masks"} if settings["file_format"] != "lerobot" else set()  # masks are per episode file
        differences = [
            f"{OPTIONS.get(name, '--' + name.replace('_', '-'))}: {recorded.get(name)!r}, not {value!r}"
            for name, value in settings.items()
            if name not in ignored and recorded.get(name) != value
        ]
        if differences:
            raise ValueError(
                f"{out_dir} holds a collection with other settings ({'; '.join(differences)}): rerun with its "
                "settings to continue it, or collect into another folder"
            )
    elif settings["file_format"] == "lerobot":
        why = " and holds no collection of sb3-ef collect: --format lerobot writes into a new or empty folder"
        refuse_files_in(out_dir, why)


def _write_record(out_dir: str, settings: dict[str, Any]) -> None:
    """Keep the settings in ``out_dir``, leaving a file that holds them alone (a full disk still reruns)."""
    os.makedirs(out_dir, exist_ok=True)
    path, text = os.path.join(out_dir, RECORD), json.dumps(settings, indent=2)
    if not os.path.isfile(path) or Path(path).read_text() != text:
        write_text_atomically(path, text)


def _collect_files(
    recorder: _Recorder, out_dir: str, settings: dict[str, Any], episodes: int, masks: bool | Sequence[int], bar: Any
) -> list[str]:
    """One ``.npz`` / ``.h5`` file per episode; intact files already there are kept."""
    paths = [os.path.join(out_dir, f"episode_{index:05d}.{settings['file_format']}") for index in range(episodes)]
    kept = _intact_episodes(paths, recorder)
    _write_record(out_dir, settings)
    try:
        for index, path in enumerate(paths):
            if index not in kept:
                with_masks = masks if isinstance(masks, bool) else index in masks
                episode = recorder.episode(index, path, with_masks)
                with sigint_deferred():
                    write_episode(path, episode)
            bar.update(1)
    except KeyboardInterrupt:
        count = sum(os.path.isfile(path) for path in paths)
        raise Interrupted(
            f"{count} of {episodes} episodes are in {out_dir} (one still being recorded is dropped): rerun the "
            f"command to record the other {episodes - count}"
        ) from None
    others = sorted(set(glob.glob(os.path.join(out_dir, "*"))) - set(paths))
    others = [path for path in others if path.endswith(NPZ_SUFFIXES + HDF5_SUFFIXES)]
    if others:
        warnings.warn(
            f"{out_dir} also holds {len(others)} other episode files ({os.path.basename(others[0])}, ...): readers "
            "of the folder read them too",
            stacklevel=3,
        )
    return paths


def _intact_episodes(paths: list[str], recorder: _Recorder) -> set[int]:
    """The indices of the episode files that read back intact; refuses one of another frame shape or action size."""
    intact, other_shapes = set(), []
    for index, path in enumerate(paths):
        if not os.path.exists(path):
            continue
        try:
            episode = read_episode_file(path)
        except EpisodeError as error:
            warnings.warn(f"{error}: recording it again", stacklevel=4)
            continue
        if episode.frame_shape != recorder.frame_shape or episode.action_dim != recorder.action_dim:
            other_shapes.append(f"{path}: frames {episode.frame_shape} and {episode.action_dim}-d actions")
        intact.add(index)
    if other_shapes:
        raise ValueError(
            f"{other_shapes[0]}, while this collection records frames {recorder.frame_shape} and "
            f"{recorder.action_dim}-d actions (--size, ENV): collect into another folder, or with the settings that "
            f"wrote the {len(other_shapes)} episodes there"
        )
    return intact


def _collect_lerobot(recorder: _Recorder, out_dir: str, settings: dict[str, Any], episodes: int, bar: Any) -> str:
    """A LeRobot v3.0 dataset; the dataset of an interrupted collection in ``out_dir`` is continued."""
    from sb3_ef.offline.lerobot_writer import LeRobotWriter

    masks = bool(settings["masks"])
    writer = LeRobotWriter(out_dir, recorder.frame_shape, recorder.action_dim, masks=masks, append=True)
    _write_record(out_dir, settings)
    bar.update(min(writer.episodes, episodes))
    if writer.episodes >= episodes:
        return out_dir
    try:
        with writer:
            for index in range(writer.episodes, episodes):
                writer.add(recorder.episode(index, f"{out_dir} (episode {index})", masks))
                bar.update(1)
    except KeyboardInterrupt:
        raise Interrupted(
            f"{writer.episodes} of {episodes} episodes are in {out_dir}, a LeRobot dataset of those (one still being "
            f"recorded is dropped): rerun the command to record the other {episodes - writer.episodes}"
        ) from None
    return out_dir


def _make_env(name: str, size: int, frame_stack: int, action_repeat: int, fast_render: bool, **kwargs: Any) -> Any:
    """``make_env`` for dmc/ and metaworld/ names, ``gym.make`` for other registered sb3-ef envs."""
    if name.startswith(("dmc/", "metaworld/")):
        from sb3_ef.envs import make_env

        return make_env(
            name, size=size, frame_stack=frame_stack, action_repeat=action_repeat, fast_render=fast_render, **kwargs
        )
    import gymnasium as gym

    import sb3_ef  # noqa: F401  (registers the envs)

    try:
        return gym.make(name, size=size, frame_stack=frame_stack, **kwargs)
    except gym.error.Error as error:  # an unknown id or version: gymnasium's message suggests the right one
        raise ValueError(
            f"Unknown env {name!r}: {error} (sb3-ef envs: dmc/<domain>-<task>, metaworld/<task>, toy/agent-v0)"
        ) from None
