"""The loss side of the auxiliary-loss interface (EF, SEAR, CURL, yours), and the policies that carry one."""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping
from typing import Any, cast

import torch as th
from stable_baselines3.common.utils import get_device
from torch import nn


class AuxiliaryLoss(nn.Module, ABC):
    """An auxiliary representation loss: a component its host holds and calls, in this order, in each update.

    1. ``observations, targets = loss.prepare(batch, pad, generator)``: the augmented observations the host encodes
       and what the loss compares against, augmented consistently; the loss's own draws come from ``generator``.
    2. ``features = <the host's encoder>(observations)``; the host computes its own loss on them.
    3. ``weighted, logs = loss(features, targets)``: the loss already weighted by its coefficients, and its
       detached, unweighted parts, which the host logs as ``train/<name>``.
    4. The host adds ``weighted`` to its own loss (or steps it apart) and steps the optimiser that holds this
       module's parameters: which one is the host's choice, made visibly in its ``_setup_model``.
    5. ``loss.after_update(encoder)``: after the optimiser steps (a momentum target follows ``encoder``).

    Coefficients (EF's ``beta``, SEAR's weights) live once, here, as registered buffers
    (:meth:`register_coefficient`): saved with the module's state, read and set through the module
    (``loss.beta.fill_(0.5)``), and a state saved before a coefficient existed loads with its constructed value.
    """

    _coefficients: tuple[str, ...] = ()

    def register_coefficient(self, name: str, value: float) -> None:
        """Keep the loss weight ``name`` as a float64 buffer of this module (the value as given: ``model.beta``
        reads back 0.01, not its float32 neighbour); :meth:`weighted` applies it in the loss's dtype."""
        self.register_buffer(name, th.tensor(float(value), dtype=th.float64))
        self._coefficients = (*self._coefficients, name)

    def weighted(self, weight: th.Tensor, loss: th.Tensor) -> th.Tensor:
        """``weight * loss`` in ``loss``'s dtype: the coefficient rounded once, as a Python float would be."""
        return weight.to(loss.dtype) * loss

    @abstractmethod
    def prepare(self, batch: Any, pad: int, generator: th.Generator | None = None) -> tuple[th.Tensor, Any]:
        """Augment the batch's observations for the host's encoder; return them and the loss's targets."""

    @abstractmethod
    def forward(self, features: th.Tensor, targets: Any) -> tuple[th.Tensor, dict[str, th.Tensor]]:
        """The weighted loss on encoder ``features`` of the prepared observations, and its logged parts."""

    def after_update(self, encoder: nn.Module) -> None:
        """Called after the optimiser steps of each update; nothing by default."""

    def _load_from_state_dict(
        self,
        state_dict: dict[str, Any],
        prefix: str,
        local_metadata: dict[str, Any],
        strict: bool,
        missing_keys: list[str],
        unexpected_keys: list[str],
        error_msgs: list[str],
    ) -> None:
        super()._load_from_state_dict(
            state_dict, prefix, local_metadata, strict, missing_keys, unexpected_keys, error_msgs
        )
        for name in self._coefficients:
            if prefix + name in missing_keys:
                missing_keys.remove(prefix + name)


class CarriesAuxiliary:
    """For a policy that carries its algorithm's auxiliary module as ``policy.auxiliary``: ``policy.save`` and
    ``Policy.load`` keep it; a policy file without one loads without it."""

    auxiliary: AuxiliaryLoss | None

    def save(self, path: str) -> None:
        """SB3's policy file, with the auxiliary module (pickled whole, as SB3 pickles the policy's arguments)."""
        model = cast(Any, self)
        th.save(
            {
                "state_dict": model.state_dict(),
                "data": model._get_constructor_parameters(),
                "auxiliary": getattr(self, "auxiliary", None),
            },
            path,
        )

    @classmethod
    def load(cls, path: str, device: th.device | str = "auto") -> Any:
        """SB3's ``Policy.load``, with the auxiliary module the file holds."""
        device = get_device(device)
        saved = th.load(path, map_location=device, weights_only=False)  # SB3's policy files pickle gymnasium spaces
        policy = cls(**saved["data"])
        if saved.get("auxiliary") is not None:
            policy.auxiliary = saved["auxiliary"]
        policy.load_state_dict(saved["state_dict"])
        return cast(Any, policy).to(device)

    def load_state_dict(self, state_dict: Mapping[str, Any], strict: bool = True, assign: bool = False) -> Any:
        if getattr(self, "auxiliary", None) is None:
            state_dict = {name: value for name, value in state_dict.items() if not name.startswith("auxiliary.")}
        return super().load_state_dict(state_dict, strict, assign)  # type: ignore[misc]
