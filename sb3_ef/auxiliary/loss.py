"""The loss side of the auxiliary-loss interface: per update ``prepare``, the host's encoder, ``forward``, then
``after_update`` (docs/architecture.md, "Auxiliary losses")."""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping
from typing import Any, cast

import torch as th
from stable_baselines3.common.utils import get_device
from torch import nn


class AuxiliaryLoss(nn.Module, ABC):
    """Base class of the auxiliary representation losses (see the module docstring for the calling protocol)."""

    @abstractmethod
    def prepare(self, batch: Any, pad: int, generator: th.Generator | None = None) -> tuple[th.Tensor, Any]:
        """Augment the batch's observations for the host's encoder; return them and the loss's targets."""

    @abstractmethod
    def forward(self, features: th.Tensor, targets: Any) -> tuple[th.Tensor, dict[str, th.Tensor]]:
        """The weighted loss on encoder ``features`` of the prepared observations, and its logged parts."""

    def after_update(self, encoder: nn.Module) -> None:
        """Called after the optimiser steps of each update; nothing by default."""


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
