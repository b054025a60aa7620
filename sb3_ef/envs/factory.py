"""``make_env``: the one entry point that builds a pixel environment from its name."""

from __future__ import annotations

import dataclasses
import inspect
from typing import TYPE_CHECKING, Any

import gymnasium as gym
import numpy as np

from sb3_ef.common.validation import did_you_mean
from sb3_ef.envs.backend import ensure_gl_backend
from sb3_ef.envs.tasks import parse_env_name

if TYPE_CHECKING:  # imported when an env is made (each needs its simulator)
    from sb3_ef.envs.distracting.env import DistractingDMCPixelEnv
    from sb3_ef.envs.dmc import DMCPixelEnv
    from sb3_ef.envs.meta_world import MetaWorldPixelEnv

#: Smallest and largest frame size accepted (the encoders need at least ~32 pixels).
MIN_SIZE, MAX_SIZE = 32, 512

#: Options of each suite's env class beyond :func:`make_env`'s own arguments.
_DMC_OPTIONS = ("episode_length", "render_mode")
SUITE_OPTIONS = {
    "dmc": _DMC_OPTIONS,
    "metaworld": ("episode_length", "resample_task", "repeat_discount", "render_mode"),
    "dmc-distracting": (*_DMC_OPTIONS, "distraction", "difficulty", "dynamic", "background_dir", "background_videos"),
}
#: Name prefixes of the ids :func:`make_env` builds (it repeats actions); other ids go through ``gym.make``.
MAKE_ENV_SUITES = tuple(f"{suite}/" for suite in SUITE_OPTIONS)


def make_env(
    name: str,
    size: int = 84,
    frame_stack: int = 3,
    action_repeat: int = 2,
    camera: int | str | None = None,
    fast_render: bool = False,
    seed: int | None = None,
    agent_masks: bool = False,
    **kwargs: Any,
):
    """Build a pixel environment: ``uint8`` observations ``(3 * frame_stack, size, size)``, actions in [-1, 1].

    :param name: ``dmc/<domain>-<task>``, ``metaworld/<task>`` or ``dmc-distracting/<domain>-<task>`` (docs/envs.md).
    :param size: frame height and width, in [MIN_SIZE, MAX_SIZE].
    :param frame_stack: frames stacked along channels, oldest first.
    :param action_repeat: simulator steps per agent step (rewards summed, success OR-ed).
    :param camera: camera index or name; default camera 0 for DMC (2 for quadruped), ``"corner"`` for Meta-World.
    :param fast_render: shadows, reflections and multisampling off: faster on CPU, other frames (keep it throughout).
    :param seed: seed of the initial states (and of the Meta-World task variant).
    :param agent_masks: every frame's agent mask in the infos (one more render per step).
    :param kwargs: suite options (:data:`SUITE_OPTIONS`), e.g. ``episode_length`` (simulator steps), ``render_mode``.
    :return: a :class:`~sb3_ef.envs.pixel_env.PixelEnv`; ``env.agent_mask()`` gives the agent's pixels.
    """
    task = parse_env_name(name)
    if not isinstance(size, (int, np.integer)) or isinstance(size, bool) or not MIN_SIZE <= size <= MAX_SIZE:
        raise ValueError(f"size must be an int in [{MIN_SIZE}, {MAX_SIZE}] (e.g. 64 or 84), got {size!r}")
    if not isinstance(agent_masks, (bool, np.bool_)):
        raise ValueError(f"agent_masks must be True or False, got {agent_masks!r}")
    if task.suite != "metaworld" and "repeat_discount" in kwargs:
        raise ValueError(f"repeat_discount (the EF authors' protocol) is a Meta-World option, got it for {name!r}")
    unknown = sorted(set(kwargs) - set(SUITE_OPTIONS[task.suite]))
    if unknown:
        accepted = [*inspect.signature(make_env).parameters, *SUITE_OPTIONS[task.suite]]
        accepted.remove("kwargs")
        raise ValueError(
            f"Unknown env option {unknown[0]!r} for {name}{did_you_mean(unknown[0], accepted)}; expected one of "
            f"{', '.join(accepted[1:])}"
        )
    ensure_gl_backend()
    env_class: type[DMCPixelEnv | MetaWorldPixelEnv | DistractingDMCPixelEnv]
    if task.suite == "dmc":
        from sb3_ef.envs.dmc import DMCPixelEnv as env_class
    elif task.suite == "dmc-distracting":
        from sb3_ef.envs.distracting.env import DistractingDMCPixelEnv as env_class
    else:
        from sb3_ef.envs.meta_world import MetaWorldPixelEnv as env_class
    options: dict[str, Any] = {"size": int(size), "frame_stack": frame_stack, "action_repeat": action_repeat}
    options.update(camera=camera, fast_render=fast_render, seed=seed, **kwargs)
    env = env_class(task.task, **options)
    env.agent_masks = bool(agent_masks)
    if agent_masks:
        options["agent_masks"] = True
    # The spec gym.make would give, so that env.spec.id names the task for envs made here too.
    registered = gym.spec(f"{task.suite}/{task.task}-v0")
    env.spec = dataclasses.replace(registered, kwargs={**registered.kwargs, **options})
    return env
