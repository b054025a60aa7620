"""The check of ``ef_kwargs``, Ego-Foresight's options as a host or ``sb3-ef pretrain`` takes them; it imports no
torch, so that a grid's dry run and the CLI refuse a bad option before any network is built (docs/ef.md)."""

from __future__ import annotations

import math
import numbers
from collections.abc import Callable, Mapping

from sb3_ef.common.validation import did_you_mean

#: What Ego-Foresight predicts: the frame at t+k (the paper) or target features of the observation at t+k.
TARGETS = ("pixel", "latent")
#: One rollout length k per batch or one per sample.
STEP_SAMPLINGS = ("batch", "sample")


def _positive_int(value: object) -> bool:
    return isinstance(value, numbers.Integral) and not isinstance(value, bool) and int(value) >= 1


def _all(value: object, test: Callable[[object], bool]) -> bool:
    return isinstance(value, (list, tuple)) and all(map(test, value))


def _is_real(value: object) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def _number(test: Callable[[float], bool]) -> Callable[[object], bool]:
    """The test of a finite real number (not a bool) that passes ``test``."""
    return lambda value: _is_real(value) and math.isfinite(value) and test(float(value))  # type: ignore[arg-type]


#: Each option of ``ef_kwargs``: what it must be, the test of a value, and the one target it applies to (or None).
OPTIONS: dict[str, tuple[str, Callable[[object], bool], str | None]] = {
    "target": (f"one of {TARGETS}", lambda value: value in TARGETS, None),
    "rollout_hidden_dims": ("a list of positive integers (hidden widths)", lambda v: _all(v, _positive_int), None),
    "decoder_channels": ("a positive integer", _positive_int, None),
    "step_sampling": (f"one of {STEP_SAMPLINGS}", lambda value: value in STEP_SAMPLINGS, None),
    "decode_batch_size": ("None (all) or a positive integer", lambda v: v is None or _positive_int(v), "pixel"),
    "projection_dim": ("a positive integer", _positive_int, "latent"),
    "head_hidden_dim": ("a positive integer", _positive_int, "latent"),
    "temperature": ("a finite positive number", _number(lambda number: number > 0), "latent"),
    "loss_scale": ("a finite number >= 0", _number(lambda number: number >= 0), "latent"),
    "target_tau": ("a number in (0, 1]", _number(lambda number: 0 < number <= 1), "latent"),
}

#: ``EgoForesight``'s arguments its callers set, which ``ef_kwargs`` cannot hold: where each is given instead.
SET_BY_CALLER = {
    "feature_dim": "the encoder's feature size",
    "action_dim": "the env's action size",
    "frame_shape": "the env's frames",
    "agent_dim": "agent_dim (beside ef_kwargs: in policy_kwargs of DrQv2EF and TDMPC2EF, an argument of SACEF, TD3EF "
    "and TQCEF, --agent-dim of sb3-ef pretrain)",
    "horizon": "the algorithm's ef_horizon (--horizon of sb3-ef pretrain)",
    "skip_channels": "the encoder (sb3-ef pretrain's dcgan-unet encoder passes U-Net skips; the RL hosts' none)",
}


def check_ef_kwargs(ef_kwargs: Mapping[str, object]) -> None:
    """Raise ``ValueError`` for an ``ef_kwargs`` key that is unknown or set elsewhere, a value of the wrong type or
    range, or an option of the other target, naming the key, what is expected and what was received."""
    if not isinstance(ef_kwargs, Mapping):
        raise ValueError(
            f"ef_kwargs must be a mapping of Ego-Foresight's options, e.g. dict(target='latent'), "
            f"got {type(ef_kwargs).__name__} {ef_kwargs!r}"
        )
    for key, value in ef_kwargs.items():
        if key in SET_BY_CALLER:
            raise ValueError(f"ef_kwargs holds {key}={value!r}, which is set by {SET_BY_CALLER[key]}")
        if key not in OPTIONS:
            raise ValueError(
                f"ef_kwargs holds an unknown option {key}={value!r}{did_you_mean(str(key), OPTIONS)}; expected "
                f"options of {', '.join(OPTIONS)}"
            )
        expected, valid, _ = OPTIONS[key]
        if not valid(value):
            received = repr(value) if _is_real(value) else f"{type(value).__name__} {value!r}"
            raise ValueError(f"ef_kwargs {key} must be {expected}, got {received}")
    target = ef_kwargs.get("target", "pixel")
    others = [key for key, value in ef_kwargs.items() if OPTIONS[key][2] not in (None, target) and value is not None]
    if others:
        default = "" if "target" in ef_kwargs else " (the default)"
        raise ValueError(
            f"ef_kwargs {others} apply to target={OPTIONS[others[0]][2]!r} only, got target={target!r}{default}"
        )
