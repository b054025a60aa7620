"""The zoo_configs YAML files: where they are, how an entry is chosen, which keys it may hold (checked up front)."""

from __future__ import annotations

import inspect
import re
from importlib import resources
from pathlib import Path
from typing import Any

import gymnasium as gym
import yaml

from sb3_ef import registry
from sb3_ef.common.validation import did_you_mean
from sb3_ef.envs.registration import is_atari

#: The ``train`` and ``enjoy`` functions (``"module:function"``) of each registry key that trains in its own loop, not
#: rl-zoo3's; by path, as they live in the workbench package of that algorithm, above the zoo.
OWN_LOOPS = {"dreamerv3": ("sb3_ef.dreamerv3.zoo_run:train_main", "sb3_ef.dreamerv3.zoo_run:enjoy_main")}
#: Algorithm keys this package registers in rl-zoo3, and those whose configs hold the paper's tasks and settings.
ZOO_ALGORITHMS = tuple(key for key in registry.ALGORITHMS if key not in OWN_LOOPS)
PAPER_ALGORITHMS = tuple(key for key in registry.keys(paper=True) if key not in OWN_LOOPS)
BENCHMARK_ALGORITHMS = tuple(registry.ALGORITHMS)

#: Keys rl-zoo3's ExperimentManager consumes before the remaining ones reach the algorithm constructor.
ZOO_KEYS = frozenset(
    {"n_timesteps", "n_envs", "env_kwargs", "normalize", "env_wrapper", "vec_env_wrapper", "callback", "monitor_kwargs"}
)

#: Constructor arguments rl-zoo3 sets itself (from its command line); an entry repeating them breaks construction.
SET_BY_ZOO = frozenset({"self", "env", "tensorboard_log", "seed", "verbose", "device", "_init_setup_model"})

#: Keys rl-zoo3 turns into schedules: a number, or a string ``lin_<initial value>``.
SCHEDULE_KEYS = frozenset({"learning_rate"})

#: rl-zoo3's action-noise keys: SB3's action noise, for the SB3 hosts (TD3-EF explores with it).
NOISE_KEYS = frozenset({"noise_type", "noise_std"})

#: Keys that exist in rl-zoo3 but do not fit these algorithms, with the reason.
REJECTED_KEYS = {"frame_stack": "frames are stacked inside the env: use env_kwargs: {frame_stack: k}"}
#: Keys that do not fit the paper's algorithms, with the reason.
REJECTED_PAPER_KEYS = dict.fromkeys(
    NOISE_KEYS, "the algorithms explore with their own noise schedules, not SB3 action noise"
)


def default_config_path(algo: str) -> Path:
    """``zoo_configs/<algo>.yml``, shipped in the package as ``sb3_ef/zoo/configs/`` (a link in a source checkout)."""
    if algo not in BENCHMARK_ALGORITHMS:
        raise ValueError(f"No default zoo config for algorithm {algo!r}: expected one of {BENCHMARK_ALGORITHMS}")
    path = Path(str(resources.files("sb3_ef.zoo") / "configs" / f"{algo}.yml"))
    if not path.is_file():
        raise FileNotFoundError(f"Default zoo config {path} not found: pass --conf-file explicitly")
    return path


def load_config(path: str | Path) -> dict[str, dict[str, Any]]:
    """Read a zoo YAML file: a mapping from env id (or ``default``) to a mapping of hyperparameters."""
    with open(path) as file:
        config = yaml.safe_load(file)
    if not isinstance(config, dict) or not all(isinstance(entry, dict) for entry in config.values()):
        raise ValueError(f"{path}: expected a mapping of env id -> mapping of hyperparameters")
    return config


def select_entry(config: dict[str, dict[str, Any]], env_id: str) -> dict[str, Any]:
    """The entry rl-zoo3 would use for ``env_id``: its own, else ``atari`` (an ALE game), else ``default`` (a copy)."""
    if env_id in config:
        return dict(config[env_id])
    if "atari" in config and is_atari(env_id):
        return dict(config["atari"])
    if "default" in config:
        return dict(config["default"])
    raise ValueError(f"No entry for env {env_id!r} and no 'default' entry; entries: {sorted(config)}")


def allowed_keys(algo_class: type) -> frozenset[str]:
    """Keys an entry may hold for ``algo_class``: its constructor arguments (bases' included) and rl-zoo3's."""
    parameters: set[str] = set()
    for cls in algo_class.__mro__:
        init = vars(cls).get("__init__")
        if init is None or not inspect.isfunction(init):
            continue
        signature = inspect.signature(init).parameters
        parameters |= {name for name, p in signature.items() if p.kind not in (p.VAR_KEYWORD, p.VAR_POSITIONAL)}
        if not any(p.kind is p.VAR_KEYWORD for p in signature.values()):
            break
    return frozenset(parameters) - SET_BY_ZOO | ZOO_KEYS


def check_keys(algo: str, algo_class: type, keys: Any, where: str) -> None:
    """Raise ``ValueError`` naming the first key that ``algo_class`` (through rl-zoo3) would not accept; an ``algo``
    outside the registry is one of rl-zoo3's own (SB3's classes: every rl-zoo3 key)."""
    item = registry.ALGORITHMS.get(algo, registry.AlgorithmEntry(algo, "", zoo_frame_stack=True))
    allowed = allowed_keys(algo_class) | (frozenset() if item.own_exploration else NOISE_KEYS)
    allowed |= {"frame_stack"} if item.zoo_frame_stack else frozenset()
    rejected = {
        **({} if item.zoo_frame_stack else REJECTED_KEYS),
        **(REJECTED_PAPER_KEYS if item.own_exploration else {}),
    }
    for key in keys:
        if key in rejected:
            raise ValueError(f"{where}: key {key!r} is not supported for {algo}: {rejected[key]}")
        if key not in allowed:
            raise ValueError(
                f"{where}: unknown key {key!r} for {algo}{did_you_mean(key, allowed)}; "
                f"expected one of {sorted(allowed)}"
            )


#: rl-zoo3 callbacks that cannot work with sb3-ef's algorithms, with the reason and what to do instead.
REFUSED_CALLBACKS = {
    "ParallelTrainCallback": "it trains a copy of the model reloaded as SB3's SAC or TQC, without the auxiliary loss "
    "(EF, SEAR, CURL) or sb3-ef's update; leave it out and trade speed with train_freq and gradient_steps instead",
}


def check_values(values: dict[str, Any], where: str) -> None:
    """Refuse a string where rl-zoo3 expects a number or ``lin_<initial>``, and a refused ``callback``."""
    for name, reason in REFUSED_CALLBACKS.items():
        if name in repr(values.get("callback", "")):
            raise ValueError(f"{where}: callback {name} is not supported with sb3-ef's algorithms: {reason}")
    for key in SCHEDULE_KEYS & set(values):
        value = values[key]
        if isinstance(value, str) and re.fullmatch(r"lin_[-+0-9.eE]+", value) is None:
            raise ValueError(
                f"{where}: {key} must be a number or rl-zoo3's linear schedule 'lin_<initial value>', got the string "
                f"{value!r}"
            )


def validate_config(algo: str, algo_class: type, config: dict[str, dict[str, Any]], source: str = "config") -> None:
    """Check every entry of a zoo config; a ``ValueError`` names the entry and the key or id."""
    for name, entry in config.items():
        where = f"{source}, entry {name!r}"
        if name not in ("default", "atari") and name not in gym.envs.registry:
            raise ValueError(f"{where}: env id {name!r} is not registered with gymnasium (did `import sb3_ef` run?)")
        check_keys(algo, algo_class, entry, where)
        check_values(entry, where)
        for required in ("policy", "n_timesteps"):
            if required not in entry:
                raise ValueError(f"{where}: missing required key {required!r}")
