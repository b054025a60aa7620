"""Warm-starting an RL agent from an offline-pretrained model: copy the encoder and Ego-Foresight weights."""

from __future__ import annotations

import os
from typing import Any, cast

import torch as th
from torch import nn

from sb3_ef import registry
from sb3_ef.ef.losses import LatentForesightLoss
from sb3_ef.offline.encoders import HostEncoder
from sb3_ef.offline.model import OfflineEF, load_pretrained

#: Which pretrained encoder each host uses, and where the host keeps it.
HOST_ENCODERS = {"DrQv2Policy": ("drqv2", "encoder"), "TDMPC2Policy": ("tdmpc2", "world_model.encoder")}


def _host_encoder(policy: nn.Module) -> tuple[str, nn.Module]:
    for cls in type(policy).__mro__:
        if cls.__name__ in HOST_ENCODERS:
            kind, attribute = HOST_ENCODERS[cls.__name__]
            module: Any = policy
            for name in attribute.split("."):
                module = getattr(module, name)
            return kind, module
    supported = " and ".join(registry.entry(key).class_name for key in registry.keys(warm_start=True))
    raise TypeError(f"Warm start supports {supported}, got a model with policy {type(policy).__name__}")


def _mismatches(source: nn.Module, target: nn.Module) -> list[str]:
    source_state, target_state = source.state_dict(), target.state_dict()
    problems = [f"{key}: missing in the RL model" for key in source_state if key not in target_state]
    problems += [f"{key}: missing in the pretrained model" for key in target_state if key not in source_state]
    problems += [
        f"{key}: pretrained {tuple(value.shape)}, RL model {tuple(target_state[key].shape)}"
        for key, value in source_state.items()
        if key in target_state and value.shape != target_state[key].shape
    ]
    return problems


def load_ef(model: Any, pretrained: str | os.PathLike | OfflineEF) -> Any:
    """Copy a pretrained encoder and ``EgoForesight`` into a DrQv2EF / TDMPC2EF of the same architecture.

    :param model: a DrQv2EF or TDMPC2EF (``model.policy`` holds the networks).
    :param pretrained: a ``model.pt`` / ``checkpoint.pt`` written by ``pretrain``, or an :class:`OfflineEF`.
    :raises ValueError: naming every setting, parameter or shape that differs.
    :return: ``model``, for chaining.
    """
    source = pretrained if isinstance(pretrained, OfflineEF) else load_pretrained(pretrained)[0]
    name = os.fspath(pretrained) if not isinstance(pretrained, OfflineEF) else "the pretrained model"
    if getattr(model, "ef", None) is None:
        raise ValueError(
            f"{type(model).__name__} has no Ego-Foresight module (model.ef is None): nothing to warm-start"
        )
    kind, encoder = _host_encoder(model.policy)
    config = source.config
    problems = []
    if config.encoder != kind:
        problems.append(f"encoder: pretrained {config.encoder!r}, {type(model).__name__} needs {kind!r}")
    stack = model.observation_space.shape[0] // 3
    if config.context != stack:
        problems.append(f"context frames: pretrained {config.context}, RL model stacks {stack}")
    if tuple(config.frame_shape) != tuple(model.frame_shape):
        problems.append(f"frame shape: pretrained {tuple(config.frame_shape)}, RL model {tuple(model.frame_shape)}")
    if not problems:
        pretrained_net = cast(HostEncoder, source.encoder).net  # built for the host's encoder kind
        problems = [f"encoder {p}" for p in _mismatches(pretrained_net, encoder)]
        problems += [f"ef {p}" for p in _mismatches(source.ef, model.ef)]
    if problems:
        raise ValueError(f"Cannot warm-start {type(model).__name__} from {name}:\n  " + "\n  ".join(problems))
    with th.no_grad():
        encoder.load_state_dict(pretrained_net.state_dict())
        model.ef.load_state_dict(source.ef.state_dict())
    if isinstance(model.auxiliary, LatentForesightLoss):
        # Latent EF: its momentum target restarts from the warm-started encoder and projection.
        model.auxiliary.target_encoder.copy_from(encoder, model.ef.head.projection)
    return model
