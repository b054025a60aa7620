"""rl-zoo3 plug-in: registers the algorithms of ``sb3_ef.registry`` that rl-zoo3 trains (``drqv2_ef``, ``drqv2``,
``tdmpc2_ef``, ``tdmpc2``, ``sear``, ``curl``, ``sac_ef``, ``td3_ef``, ``tqc_ef``) with their Optuna samplers;
``dreamerv3`` takes the same commands in sheeprl's loop (:mod:`sb3_ef.zoo.sheeprl_run`).

Entry points: ``python -m sb3_ef.zoo.train`` and ``python -m sb3_ef.zoo.enjoy`` (rl-zoo3's arguments), or the
``sb3-ef`` console script. See docs/zoo.md. The public names are imported on first use (rl-zoo3 imports torch), so
that the command line can check its arguments first.
"""

from __future__ import annotations

from sb3_ef.common.lazy import lazy_attributes

_PUBLIC = {
    "ZOO_ALGORITHMS": "sb3_ef.zoo.config",
    "default_config_path": "sb3_ef.zoo.config",
    "validate_config": "sb3_ef.zoo.config",
    "register_algorithms": "sb3_ef.zoo.registration",
}

__all__ = list(_PUBLIC)

__getattr__ = lazy_attributes(__name__, _PUBLIC)
