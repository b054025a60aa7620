"""Register sb3-ef's algorithms with rl-zoo3 without forking it.

rl-zoo3 looks algorithms up in ``rl_zoo3.utils.ALGOS`` and Optuna samplers in ``rl_zoo3.hyperparams_opt``'s two
dictionaries; all its modules share those dictionary objects, so adding our keys in place is enough. It evaluates
strings from the YAML files (``policy_kwargs``, ``replay_buffer_class``, ...) and ``--hyperparams`` values in the
namespaces of ``rl_zoo3.exp_manager`` and ``rl_zoo3.utils``; the names a config may use are added there.
"""

from __future__ import annotations

from functools import partial
from typing import Any

from rl_zoo3 import exp_manager, hyperparams_opt, utils

from sb3_ef import registry
from sb3_ef.zoo.hyperparams_opt import CONVERTERS, SAMPLERS


def algorithm_classes() -> dict[str, type]:
    """rl-zoo3 key -> algorithm class, for the registry's algorithms that rl-zoo3 trains (imported now: they pull in
    torch)."""
    return {key: registry.entry(key).algorithm_class for key in registry.keys(rl_zoo3=True)}


def config_namespace() -> dict[str, Any]:
    """Names a zoo config string may use, e.g. ``replay_buffer_class: SequenceReplayBuffer`` or, for the SB3 hosts
    on frames smaller than NatureCNN's 36x36, ``features_extractor_class=DrQv2Encoder`` in ``policy_kwargs``."""
    from sb3_ef.common.buffers import SequenceReplayBuffer
    from sb3_ef.drqv2.policies import DrQv2Encoder

    return {"SequenceReplayBuffer": SequenceReplayBuffer, "DrQv2Encoder": DrQv2Encoder}


def register_algorithms(base_policy_kwargs: dict[str, Any] | None = None) -> None:
    """Add the algorithms of :func:`algorithm_classes` to rl-zoo3, with the Optuna samplers and converters of those
    that have one (``sb3_ef.zoo.hyperparams_opt``).

    :param base_policy_kwargs: ``policy_kwargs`` of the config entry in use. rl-zoo3 replaces the entry's
        ``policy_kwargs`` with the sampled ones; the samplers merge into these instead, so tuning ``agent_dim`` keeps
        the entry's other policy settings.
    """
    utils.ALGOS.update(algorithm_classes())
    for key, sampler in SAMPLERS.items():
        hyperparams_opt.HYPERPARAMS_SAMPLER[key] = partial(sampler, base_policy_kwargs=base_policy_kwargs)
        hyperparams_opt.HYPERPARAMS_CONVERTER[key] = partial(CONVERTERS[key], base_policy_kwargs=base_policy_kwargs)
    for module in (exp_manager, utils):
        vars(module).update(config_namespace())
