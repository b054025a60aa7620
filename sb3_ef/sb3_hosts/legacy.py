"""Models saved by sb3-ef 0.1.0, where SAC-EF, TD3-EF and TQC-EF kept the EF module inside the policy."""

from __future__ import annotations

from typing import Any

import torch as th
from stable_baselines3.common.save_util import load_from_zip_file


def ef_weights_apart(load_path_or_dict: str | dict[str, Any], device: th.device | str) -> dict[str, Any]:
    """The state dicts to load (read from the zip when given a path), with EF's weights (``ef.*`` inside
    ``policy``, as sb3-ef 0.1.0 saved them) moved to ``ef_module``, where the algorithms keep EF."""
    if isinstance(load_path_or_dict, dict):
        params = load_path_or_dict
    else:
        _, params, _ = load_from_zip_file(load_path_or_dict, device=device)
    if "ef_module" in params or "policy" not in params:
        return params
    policy = dict(params["policy"])
    ef = {name.removeprefix("ef."): policy.pop(name) for name in list(policy) if name.startswith("ef.")}
    return {**params, "policy": policy, "ef_module": ef} if ef else params
