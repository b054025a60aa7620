"""Models saved by sb3-ef 0.1.0, where SAC-EF, TD3-EF and TQC-EF kept the EF module inside the policy."""

from __future__ import annotations

from typing import Any

import torch as th
from stable_baselines3.common.save_util import load_from_zip_file


def saved_by_0_1_0_renamed(load_path_or_dict: str | dict[str, Any], device: th.device | str) -> dict[str, Any]:
    """The state dicts to load (read from the zip when given a path); those of a model saved by sb3-ef 0.1.0 are
    renamed to where the algorithms keep them: EF's weights (``ef.*`` inside ``policy``) to ``auxiliary_module``
    (whose Ego-Foresight module is its ``ef``), and ``ef_optimizer`` to ``auxiliary_optimizer``."""
    if isinstance(load_path_or_dict, dict):
        params = load_path_or_dict
    else:
        _, params, _ = load_from_zip_file(load_path_or_dict, device=device)
    if "auxiliary_module" in params or "policy" not in params:
        return params
    policy = dict(params["policy"])
    ef = {name: policy.pop(name) for name in list(policy) if name.startswith("ef.")}
    if not ef:
        return params
    renamed = {key: value for key, value in params.items() if key != "ef_optimizer"}
    renamed.update(policy=policy, auxiliary_module=ef)
    if "ef_optimizer" in params:
        renamed["auxiliary_optimizer"] = params["ef_optimizer"]
    return renamed
