"""sheeprl's configuration of a Dreamer-v3 run: preset, recipe, overrides and the run's fixed session."""

from __future__ import annotations

import importlib
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any

from sb3_ef.common.validation import PRECISIONS, check_choice, did_you_mean

#: The sheeprl release this package drives (its configuration keys and checkpoint contents).
SHEEPRL_VERSION = "0.8.4"
#: sheeprl's Dreamer-v3 model presets (``sheeprl/configs/algo/dreamer_v3_<size>.yaml``).
MODEL_SIZES = ("XS", "S", "M", "L", "XL")
FRAME_KEY = "rgb"
_OVERRIDES_FORM = (
    "sheeprl_overrides must be a dict of sheeprl's keys to values, dotted ({'algo.horizon': 15}) or nested "
    "({'algo': {'horizon': 15}})"
)
#: Lightning Fabric's precision for each value of ``precision``.
FABRIC_PRECISION = {"fp32": "32-true", "bf16": "bf16-mixed"}
#: Keys (and the sections below them) that the run sets itself, with the argument that sets them instead.
SESSION_KEYS = {
    "seed": "seed", "algo.total_steps": "learn(total_timesteps)", "algo.per_rank_batch_size": "batch_size",
    "algo.per_rank_sequence_length": "sequence_length", "algo.replay_ratio": "replay_ratio",
    "algo.learning_starts": "learning_starts", "algo.cnn_keys": "the env (frames only)",
    "algo.mlp_keys": "the env (frames only)", "algo.run_test": "learn's evaluation", "buffer.size": "buffer_size",
    "buffer.checkpoint": "the run (replay buffers are checkpointed)", "env": "env",
    "checkpoint": "learn's checkpoint_freq / keep_checkpoints", "fabric.accelerator": "device",
    "fabric.devices": "device", "fabric.precision": "precision", "fabric.num_nodes": "the run (one device)",
    "fabric.strategy": "the run (one device)",
    "fabric.callbacks": "the run (evaluation and checkpoints)", "log_root": "work_dir", "root_dir": "work_dir",
    "run_name": "work_dir", "model_manager": "the run (no MLflow)", "dry_run": "the run",
}  # fmt: skip


def require_sheeprl() -> Any:
    """Import sheeprl, or raise an ImportError that names the extra to install."""
    try:
        return importlib.import_module("sheeprl")
    except ImportError as error:
        raise ImportError(
            f"DreamerV3 runs sheeprl's Dreamer-v3 (sheeprl=={SHEEPRL_VERSION}); install it with: "
            "pip install -e .[dreamerv3]  (or pip install sb3-ef[dreamerv3])"
        ) from error


@dataclass(frozen=True)
class Recipe:
    """The algorithm's settings (:class:`~sb3_ef.dreamerv3.DreamerV3`'s arguments, in sheeprl's terms)."""

    model_size: str = "S"
    replay_ratio: float = 0.5
    batch_size: int = 16
    sequence_length: int = 64
    buffer_size: int = 1_000_000
    learning_starts: int = 1024
    sheeprl_overrides: Mapping[str, Any] = field(default_factory=dict)
    precision: str = "fp32"

    def __post_init__(self) -> None:
        check_choice("precision", self.precision, PRECISIONS)
        if self.model_size not in MODEL_SIZES:
            raise ValueError(f"model_size must be one of {MODEL_SIZES}, got {self.model_size!r}")
        if isinstance(self.replay_ratio, bool) or not isinstance(self.replay_ratio, (int, float)):
            raise ValueError(f"replay_ratio must be a number of gradient steps per env step, got {self.replay_ratio!r}")
        if self.replay_ratio <= 0:
            raise ValueError(f"replay_ratio must be > 0 gradient steps per env step, got {self.replay_ratio}")
        for name, least in (("batch_size", 1), ("sequence_length", 1), ("buffer_size", 1), ("learning_starts", 0)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < least:
                raise ValueError(f"{name} must be an integer >= {least}, got {value!r}")
        if self.buffer_size < self.sequence_length:
            raise ValueError(
                f"buffer_size ({self.buffer_size}) must hold one sequence of sequence_length ({self.sequence_length})"
            )
        if not isinstance(self.sheeprl_overrides, Mapping):
            given = self.sheeprl_overrides
            raise ValueError(f"{_OVERRIDES_FORM}, got {given!r} ({type(given).__name__})")
        overrides = _dotted(self.sheeprl_overrides)
        object.__setattr__(self, "sheeprl_overrides", overrides)  # a copy: the caller's dict may change
        for key in overrides:
            for session_key, argument in SESSION_KEYS.items():
                if key == session_key or key.startswith(session_key + "."):
                    raise ValueError(f"sheeprl_overrides: {key!r} is set by DreamerV3 from {argument}, not here")


def _dotted(overrides: Mapping[Any, Any], prefix: str = "") -> dict[str, Any]:
    """``overrides`` with nested dicts merged key by key: ``{"algo": {"horizon": 15}}`` -> ``{"algo.horizon": 15}``."""
    dotted: dict[str, Any] = {}
    for key, value in overrides.items():
        if not isinstance(key, str):
            raise ValueError(f"{_OVERRIDES_FORM}, got the key {key!r} ({type(key).__name__})")
        dotted.update(_dotted(value, f"{prefix}{key}.") if isinstance(value, Mapping) else {prefix + key: value})
    return dotted


def _dotted_keys(cfg: Any, prefix: str = "") -> Iterator[str]:
    """Every key of a configuration, dotted, sections included."""
    from omegaconf import OmegaConf

    for key in cfg:
        dotted = f"{prefix}{key}"
        yield dotted
        node = cfg._get_node(key)
        if OmegaConf.is_dict(node):
            yield from _dotted_keys(node, dotted + ".")


def _type_mismatch(current: Any, value: Any) -> str | None:
    """What ``value`` should be to replace ``current`` (``None`` on either side fits), or ``None`` when it fits."""
    from omegaconf import OmegaConf

    if current is None or value is None:
        return None
    kinds: tuple[tuple[bool, str, bool], ...] = (
        (isinstance(current, bool), "true or false", isinstance(value, bool)),
        (isinstance(current, int), "a whole number", isinstance(value, int) and not isinstance(value, bool)),
        (isinstance(current, float), "a number", isinstance(value, (int, float)) and not isinstance(value, bool)),
        (isinstance(current, str), "a string", isinstance(value, str)),
        (OmegaConf.is_list(current), "a list", isinstance(value, (list, tuple))),
        (OmegaConf.is_dict(current), "a dict (a section)", isinstance(value, Mapping)),
    )
    for applies, expected, fits in kinds:
        if applies:
            return None if fits else expected
    return None


def _set(cfg: Any, key: str, value: Any, typed: bool = True) -> None:
    """Set an existing key of sheeprl's configuration, refusing a typo or a value of another type (``typed``)."""
    from omegaconf import OmegaConf

    parent_key, _, leaf = key.rpartition(".")
    parent = OmegaConf.select(cfg, parent_key) if parent_key else cfg
    if parent is None or not OmegaConf.is_dict(parent) or leaf not in parent:
        hint = did_you_mean(key, list(_dotted_keys(cfg)))
        raise ValueError(f"sheeprl_overrides: {key!r} is not a key of sheeprl's Dreamer-v3 configuration{hint}")
    current = OmegaConf.select(cfg, key, throw_on_missing=False)
    expected = _type_mismatch(current, value) if typed else None
    if expected is not None:
        shown = current if not OmegaConf.is_config(current) else OmegaConf.to_container(current)
        raise ValueError(
            f"sheeprl_overrides: {key!r} must be {expected} (sheeprl's default is {shown!r}), got {value!r} "
            f"({type(value).__name__})"
        )
    OmegaConf.update(cfg, key, value, merge=False)


def compose_config(recipe: Recipe) -> Any:
    """sheeprl's Dreamer-v3 configuration (a ``DictConfig``) with ``recipe`` applied."""
    require_sheeprl()
    from hydra import compose, initialize_config_module

    with initialize_config_module("sheeprl.configs", version_base="1.3"):
        cfg = compose("config", overrides=["exp=dreamer_v3", "env=default", f"algo=dreamer_v3_{recipe.model_size}"])
    for key, value in {
        "algo.per_rank_batch_size": recipe.batch_size, "algo.per_rank_sequence_length": recipe.sequence_length,
        "algo.replay_ratio": float(recipe.replay_ratio), "algo.learning_starts": recipe.learning_starts,
        "algo.cnn_keys.encoder": [FRAME_KEY], "algo.mlp_keys.encoder": [], "algo.run_test": False,
        "buffer.size": recipe.buffer_size, "buffer.checkpoint": True, "metric.log_level": 0,
        "model_manager.disabled": True, "fabric.precision": FABRIC_PRECISION[recipe.precision],
    }.items():  # fmt: skip
        _set(cfg, key, value, typed=False)  # the recipe's own values (a float replay ratio where sheeprl has 1)
    for key, value in recipe.sheeprl_overrides.items():
        _set(cfg, key, value)
    return cfg


@dataclass(frozen=True)
class Session:
    """What one call of ``learn`` sets: the live env and callback tokens, folders, steps, checkpoints, device."""

    env_token: str
    callback_token: str
    task: str
    frame_size: int
    seed: int
    total_steps: int
    keep_last: int | None
    work_dir: str
    run_name: str
    device: str
    resume_from: str | None = None


def fabric_device(device: str) -> tuple[str, Any]:
    """Lightning's ``accelerator`` and ``devices`` for a torch device string (``auto``, ``cpu``, ``cuda:1``)."""
    kind, _, index = device.partition(":")
    if kind not in ("auto", "cpu", "cuda", "mps") or (index and not index.isdigit()):
        raise ValueError(f"device must be 'auto', 'cpu', 'cuda', 'cuda:<index>' or 'mps', got {device!r}")
    return kind, [int(index)] if index else 1


def set_session(cfg: Any, session: Session) -> None:
    """Set the session keys of ``cfg`` (also after sheeprl's resume merged the checkpoint's configuration in)."""
    from omegaconf import OmegaConf, open_dict

    accelerator, devices = fabric_device(session.device)
    with open_dict(cfg):
        cfg.update(seed=session.seed, dry_run=False, log_root=session.work_dir, root_dir="sheeprl")
        cfg.run_name = session.run_name
        cfg.algo.total_steps = session.total_steps
        # The env repeats its actions and reports its time limits itself.
        cfg.env = OmegaConf.merge(cfg.env, {
            "id": session.task, "num_envs": 1, "sync_env": True, "screen_size": session.frame_size,
            "action_repeat": 1, "grayscale": False, "capture_video": False, "max_episode_steps": None,
            "wrapper": {"_target_": "sb3_ef.dreamerv3.env.live_env", "token": session.env_token},
        })  # fmt: skip
        # sheeprl hands its state to the run's callback after every step (building it takes well under a millisecond),
        # which evaluates, writes checkpoints and calls SB3's callbacks at their own steps
        cfg.checkpoint.update(every=1, keep_last=session.keep_last, save_last=True, resume_from=session.resume_from)
        callback = {"_target_": "sb3_ef.dreamerv3.callbacks.live_callback", "token": session.callback_token}
        cfg.fabric.update(accelerator=accelerator, devices=devices, num_nodes=1, strategy="auto", callbacks=[callback])
