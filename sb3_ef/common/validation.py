"""Checks of user input shared by every algorithm and command; no torch import at load time (for the CLI)."""

from __future__ import annotations

import inspect
import math
import numbers
import os
import warnings
import zipfile
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from sb3_ef import registry
from sb3_ef.common.names import did_you_mean


def check_choice(what: str, value: Any, choices: Iterable[str]) -> None:
    """Raise ``ValueError`` when ``value`` is not one of ``choices``, suggesting the closest ones."""
    choices = list(choices)
    if value not in choices:
        hint = did_you_mean(value, choices) if isinstance(value, str) else ""
        raise ValueError(f"Unknown {what} {value!r}{hint}; expected one of {', '.join(map(repr, choices))}")


#: The ``precision`` option's values (:mod:`sb3_ef.common.precision`), here without torch for the CLI's choices.
PRECISIONS = ("fp32", "bf16")


def _is_number(value: Any) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool) and math.isfinite(float(value))


def _is_int(value: Any) -> bool:
    return isinstance(value, numbers.Integral) and not isinstance(value, bool)


def _received(value: Any) -> str:
    """Numbers as they are, anything else with its type (``str '1'``)."""
    return repr(value) if _is_number(value) else f"{type(value).__name__} {value!r}"


def _requires(expected: str, test: Callable[[Any], bool]) -> Callable[[str, Any], None]:
    """A check raising ``ValueError("<name> must be <expected>, got <value>")`` where ``test(value)`` is false."""

    def check(name: str, value: Any) -> None:
        if not test(value):
            raise ValueError(f"{name} must be {expected}, got {_received(value)}")

    return check


_positive_int = _requires("a positive integer", lambda value: _is_int(value) and value >= 1)
_non_negative_number = _requires("a number >= 0", lambda value: _is_number(value) and value >= 0)
_positive_number = _requires("a number > 0", lambda value: _is_number(value) and value > 0)
_unit_interval = _requires("a number in [0, 1]", lambda value: _is_number(value) and 0 <= value <= 1)
_learning_rate = _requires(
    "a number >= 0 or a schedule (a function of the remaining progress)",
    lambda value: callable(value) or (_is_number(value) and value >= 0),
)
_gradient_steps = _requires(
    "an integer >= 0 (0: collect without training) or -1 (as many as env steps)",
    lambda value: _is_int(value) and value >= -1,
)


def _non_negative_int(name: str, value: Any) -> None:
    _requires("an integer >= 0", _is_int)(name, value)
    if value < 0:
        raise ValueError(f"{name} must be >= 0, got {value}")


def _train_freq(name: str, value: Any) -> None:
    if (
        isinstance(value, (tuple, list))
        and len(value) == 2
        and getattr(value[1], "value", value[1]) in ("step", "episode")
    ):
        value = value[0]
    if not _is_int(value) or value < 1:
        raise ValueError(f"{name} must be a positive integer or a pair (n, 'step' | 'episode'), got {_received(value)}")


def _exploration_std(name: str, value: Any) -> None:
    from sb3_ef.common.schedules import get_step_schedule

    if callable(value):
        return
    expected = "a number >= 0, a string 'linear(initial, final, duration)' of numbers >= 0 or a callable of the step"
    if isinstance(value, bool) or not isinstance(value, (numbers.Real, str)):
        raise ValueError(f"{name} must be {expected}, got {_received(value)}")
    try:
        schedule = get_step_schedule(value if isinstance(value, str) else float(value))
    except ValueError as error:
        raise ValueError(f"{name} must be {expected}, got {_received(value)} ({error})") from None
    first, last = schedule(0), schedule(2**62)
    if not (math.isfinite(first) and math.isfinite(last)) or min(first, last) < 0:
        detail = f" (from {first:g} to {last:g})" if isinstance(value, str) else ""
        raise ValueError(f"{name} is a standard deviation: it must be {expected}, got {value!r}{detail}")


def _ent_coef(name: str, value: Any) -> None:
    if _is_number(value) and value >= 0:
        return
    if isinstance(value, str) and (value == "auto" or value.startswith("auto_")):
        try:
            initial = float(value[len("auto_") :]) if value != "auto" else 1.0
        except ValueError:
            initial = -1.0
        if math.isfinite(initial) and initial > 0:
            return
    raise ValueError(
        f"{name} must be a number >= 0 (a fixed entropy coefficient), 'auto' or 'auto_<initial value > 0>' (learned), "
        f"got {_received(value)}"
    )


_POSITIVE_INTS = ("buffer_size", "batch_size", "n_steps", "stats_window_size", "ef_horizon", "horizon", "agent_dim")
_COEFFICIENTS = ("target_noise_clip", "target_policy_noise", "consistency_coef", "reward_coef", "value_coef")
#: Argument name -> its check; ``None`` passes where the default is ``None`` and for ``beta``/``ef_horizon`` (EF off).
ARGUMENT_CHECKS: dict[str, Callable[[str, Any], None]] = {
    **dict.fromkeys(_POSITIVE_INTS, _positive_int),
    **dict.fromkeys(("learning_starts", "babbling_steps", "shift_pad"), _non_negative_int),
    **dict.fromkeys(("tau", "gamma", "rho"), _unit_interval),
    **dict.fromkeys((*_COEFFICIENTS, "entropy_coef"), _non_negative_number),
    "learning_rate": _learning_rate,
    "train_freq": _train_freq,
    "gradient_steps": _gradient_steps,
    "max_grad_norm": _positive_number,
    "exploration_std": _exploration_std,
    "ent_coef": _ent_coef,
}

_EF_OFF = frozenset({"beta", "ef_horizon"})


def _functions(target: Callable[..., Any]) -> list[Any]:
    """A function itself, or the ``__init__`` functions a class defines along its MRO."""
    functions = [vars(base).get("__init__") for base in target.__mro__] if isinstance(target, type) else [target]
    return [function for function in functions if inspect.isfunction(function)]


def _defaults(algo_class: type) -> dict[str, Any]:
    """Constructor defaults of ``algo_class``, its own first, then those of the classes it forwards ``**kwargs`` to."""
    signatures = [inspect.signature(init).parameters.values() for init in reversed(_functions(algo_class))]
    return {p.name: p.default for parameters in signatures for p in parameters if p.default is not p.empty}


def _accepted_arguments(target: Callable[..., Any]) -> set[str] | None:
    """The keyword arguments of a function or class (along the MRO's ``**kwargs``); ``None`` when any name is taken."""
    names: set[str] = set()
    for function in _functions(target):
        parameters = inspect.signature(function).parameters.values()
        names.update(parameter.name for parameter in parameters if parameter.kind in _NAMED)
        if all(parameter.kind is not inspect.Parameter.VAR_KEYWORD for parameter in parameters):
            return names - {"self"}
    return None


_NAMED = (inspect.Parameter.POSITIONAL_OR_KEYWORD, inspect.Parameter.KEYWORD_ONLY)
#: Ego-Foresight's arguments and its classes (the registry's ``ef`` keys), named when one is given to another class.
_EF_NAMES = [registry.ALGORITHMS[key].class_name for key in registry.keys(ef=True)]
EF_CLASSES = f"Ego-Foresight's classes {', '.join(_EF_NAMES[:-1])} and {_EF_NAMES[-1]}"
EF_ARGUMENTS = ("beta", "ef_horizon", "agent_dim", "ef_kwargs", "babbling_steps", "babbling_mode", "babbling_in_eval")


def _check_argument_names(name: str, accepted: set[str] | None, given: Mapping[str, Any]) -> None:
    """Raise ``TypeError`` for an argument the class does not take (before the class it forwards to does)."""
    for key, value in given.items():
        if accepted is None or key in accepted:
            continue
        owner = f" (an argument of {EF_CLASSES})" if key in EF_ARGUMENTS else ""
        raise TypeError(
            f"{name} takes no argument {key}={value!r}{owner}{did_you_mean(key, accepted)}; see help({name})"
        )


def _check_policy_kwargs(name: str, accepted: set[str] | None, policy: Any, policy_kwargs: Any) -> None:
    """Raise ``ValueError`` for a ``policy_kwargs`` entry the policy does not take, saying where it belongs."""
    taken = _accepted_arguments(policy) if isinstance(policy, type) else None
    if taken is None or not isinstance(policy_kwargs, Mapping):
        return
    extractor = policy_kwargs.get("features_extractor_class") or _defaults(policy).get("features_extractor_class")
    for key, value in policy_kwargs.items():
        if key in taken:
            continue
        if accepted is not None and key in accepted:
            where = f"it is {name}'s own argument: {name}(..., {key}={value!r})"
        elif isinstance(extractor, type) and key in (_accepted_arguments(extractor) or ()):
            where = (
                f"it is an argument of the features extractor {extractor.__name__}: "
                f"policy_kwargs=dict(features_extractor_kwargs=dict({key}={value!r}))"
            )
        else:
            where = f"expected one of {', '.join(sorted(taken))}{did_you_mean(key, taken)}"
        raise ValueError(f"{name}: policy_kwargs holds {key}={value!r}, which {policy.__name__} does not take: {where}")


def _check_policy_fits_observations(name: str, policy: Any, env: Any, aliases: Mapping[str, Any]) -> None:
    """Raise ``ValueError`` for ``"MlpPolicy"`` on images where a ``"CnnPolicy"`` exists (it flattens raw pixels)."""
    space = getattr(env, "observation_space", None)
    if policy != "MlpPolicy" or "CnnPolicy" not in aliases or space is None:
        return
    from stable_baselines3.common.preprocessing import is_image_space

    if is_image_space(space, check_channels=False):
        raise ValueError(
            f"{name}: policy 'MlpPolicy' would flatten the env's {space.shape} frames into one vector of raw "
            "pixels; expected 'CnnPolicy' (a convolutional encoder) for image observations"
        )


def check_algorithm_arguments(algo_class: type, arguments: Mapping[str, Any]) -> None:
    """Check an sb3-ef algorithm's constructor arguments (its ``locals()``, first thing in ``__init__``)."""
    values = {key: value for key, value in arguments.items() if key not in ("self", "kwargs", "__class__")}
    forwarded = arguments.get("kwargs") or {}
    values.update(forwarded)
    defaults = _defaults(algo_class)
    name = algo_class.__name__
    accepted = _accepted_arguments(algo_class)
    _check_argument_names(name, accepted, forwarded)
    for key, value in values.items():
        check = ARGUMENT_CHECKS.get(key)
        if check is None or (value is None and (key in _EF_OFF or defaults.get(key, 0) is None)):
            continue
        check(f"{name}: {key}", value)
    policy = values.get("policy")
    aliases = getattr(algo_class, "policy_aliases", {})
    if isinstance(policy, str) and policy not in aliases:
        raise ValueError(
            f"{name}: unknown policy {policy!r}{did_you_mean(policy, aliases)}; expected one of "
            f"{', '.join(map(repr, aliases))} or a policy class"
        )
    _check_policy_fits_observations(name, policy, values.get("env"), aliases)
    _check_policy_kwargs(name, accepted, aliases.get(policy, policy), values.get("policy_kwargs"))
    check_device(values.get("device", defaults.get("device", "auto")))


def check_keyword_arguments(
    what: str, target: Callable[..., Any], kwargs: Mapping[str, Any], set_by_caller: Iterable[str] = ()
) -> None:
    """Raise ``ValueError`` for a key of ``kwargs`` that ``target`` does not take or the caller sets itself."""
    taken = _accepted_arguments(target)
    if taken is None:
        return
    valid = sorted(taken - set(set_by_caller))
    for key in kwargs:
        if key not in valid:
            raise ValueError(
                f"unknown key {key!r} for {what}{did_you_mean(key, valid)}; expected one of {', '.join(valid)}"
            )


def check_device(device: Any) -> None:
    """Raise ``ValueError`` for a device torch cannot parse; warn when CUDA is asked for and not available."""
    import torch as th

    if device == "auto":
        return
    try:
        parsed = th.device(device)
    except (RuntimeError, TypeError) as error:
        raise ValueError(f"device must be 'auto', 'cpu', 'cuda' or 'cuda:<index>', got {device!r} ({error})") from None
    if parsed.type == "cuda" and not th.cuda.is_available():
        warnings.warn(
            f"device={device!r} was asked for but CUDA is not available: training runs on the CPU", stacklevel=3
        )


def check_learn(model: Any, total_timesteps: Any, reset_num_timesteps: bool) -> None:
    """Check ``learn``'s step count, ``learning_starts`` against it, and ``batch_size`` against ``buffer_size``."""
    valid = _is_int(total_timesteps) or (_is_number(total_timesteps) and float(total_timesteps).is_integer())
    if not valid or total_timesteps < 0:
        raise ValueError(f"total_timesteps must be a whole number of steps >= 0, got {_received(total_timesteps)}")
    final_step = int(total_timesteps) + (0 if reset_num_timesteps else model.num_timesteps)
    learning_starts = getattr(model, "learning_starts", None)
    if learning_starts is None or total_timesteps == 0:
        return
    if learning_starts >= final_step:
        warnings.warn(
            f"learning_starts={learning_starts} is not below the {final_step} steps this learn call reaches: "
            "no gradient update will run",
            stacklevel=3,
        )
        return
    batch_size, buffer_size = getattr(model, "batch_size", None), getattr(model, "buffer_size", None)
    if batch_size is not None and buffer_size is not None and batch_size > buffer_size:
        raise ValueError(
            f"batch_size={batch_size} exceeds buffer_size={buffer_size}: every batch would repeat transitions; "
            "lower batch_size or raise buffer_size"
        )


def check_observation(observation: Any, observation_space: Any) -> None:
    """Raise ``ValueError`` for a non-uint8 array given for a uint8 image space (it would be divided by 255 again)."""
    space_dtype = getattr(observation_space, "dtype", None)
    if isinstance(observation, np.ndarray) and space_dtype == np.uint8 and observation.dtype != np.uint8:
        raise ValueError(
            f"predict expects uint8 pixel observations (0-255) like the env's {observation_space}, got an array "
            f"of dtype {observation.dtype}: pass the env's frames unconverted"
        )


def is_intact(model_path: str | os.PathLike) -> bool:
    """Whether a model zip can be read: its members pass their CRC checks and it holds SB3's ``data``."""
    try:
        with zipfile.ZipFile(model_path) as archive:
            return "data" in archive.namelist() and archive.testzip() is None
    except (zipfile.BadZipFile, OSError, EOFError):
        return False


def _is_torch_file(path: Path) -> bool:
    """Whether the first zip member is ``<name>/data.pkl`` (from the first header: a cut SB3 zip may end in a stored
    ``.pth``'s central directory)."""
    try:
        with open(path, "rb") as file:
            header = file.read(30)
            if len(header) < 30 or header[:4] != b"PK\x03\x04":
                return False
            name = file.read(int.from_bytes(header[26:28], "little"))
    except OSError:
        return False
    return name.endswith(b"/data.pkl")


def check_model_path(path: Any) -> Path | None:
    """The model zip ``path`` names (``None`` for a file object); raises for a missing, PyTorch or damaged file."""
    if not isinstance(path, (str, os.PathLike)):
        return None
    given = Path(path)
    candidates = [given] if given.suffix == ".zip" else [given, given.with_name(f"{given.name}.zip")]
    found = next((candidate for candidate in candidates if candidate.is_file()), None)
    if found is None:
        tried = " or ".join(str(candidate) for candidate in candidates)
        raise FileNotFoundError(f"No saved model at {tried}")
    if _is_torch_file(found):
        raise ValueError(
            f"{found} is a PyTorch file (torch.save), not a model zip written by save(): a `sb3-ef pretrain` output "
            "(model.pt, checkpoint.pt) is read with sb3_ef.offline.load_pretrained, and its weights are copied into a "
            "DrQv2EF or TDMPC2EF with sb3_ef.offline.load_ef(model, path)"
        )
    if not is_intact(found):
        raise ValueError(
            f"{found} is not a saved model: expected a zip archive written by save() (the file may be truncated)"
        )
    return found
