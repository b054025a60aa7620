"""Pixel masks of named parts of a MuJoCo scene (a tool, a door: geoms and body subtrees) next to the agent's."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import mujoco
import numpy as np

from sb3_ef.envs.agent_geoms import agent_geoms

AGENT = "agent"


def _ids(model: mujoco.MjModel, kind: mujoco.mjtObj, names: Sequence[str], count: int, label: str) -> list[int]:
    if isinstance(names, str):
        raise TypeError(f"Expected a sequence of {label} names, got the string {names!r}")
    ids = []
    for name in names:
        index = mujoco.mj_name2id(model, kind, name)
        if index < 0:
            known = sorted(filter(None, (mujoco.mj_id2name(model, kind, i) for i in range(count))))
            raise ValueError(f"No {label} named {name!r} in this model; its {label}s are {known}")
        ids.append(index)
    return ids


def part_geoms(model: mujoco.MjModel, bodies: Sequence[str] = (), geoms: Sequence[str] = ()) -> np.ndarray:
    """Boolean ``(model.ngeom,)``: the geoms named in ``geoms`` and those in the subtrees of ``bodies``."""
    body_ids = _ids(model, mujoco.mjtObj.mjOBJ_BODY, bodies, model.nbody, "body")
    geom_ids = _ids(model, mujoco.mjtObj.mjOBJ_GEOM, geoms, model.ngeom, "geom")
    if not body_ids and not geom_ids:
        raise ValueError("A part needs at least one body or geom name")
    in_part = np.zeros(model.nbody, bool)
    in_part[body_ids] = True
    # Bodies are numbered so that a parent comes before its children: one pass marks whole subtrees.
    for body in range(1, model.nbody):
        in_part[body] |= in_part[model.body_parentid[body]]
    selection = in_part[model.geom_bodyid]
    selection[geom_ids] = True
    return selection


def part_mask(geom_ids: np.ndarray, selection: np.ndarray) -> np.ndarray:
    """Bool mask of the pixels of ``geom_ids`` (segmentation, -1 = no geom) whose geom is in ``selection``."""
    geom_ids = np.asarray(geom_ids)
    selection = np.asarray(selection, bool)
    if geom_ids.size and (geom_ids.min() < -1 or geom_ids.max() >= len(selection)):
        raise ValueError(
            f"Segmentation ids must lie in [-1, {len(selection) - 1}] for {len(selection)} geoms, "
            f"got [{geom_ids.min()}, {geom_ids.max()}]"
        )
    return np.concatenate([[False], selection])[geom_ids + 1]


class PartMasks:
    """Masks of the agent and of ``parts`` (name -> ``{"bodies": [...], "geoms": [...]}``) from one render."""

    def __init__(self, env: Any, parts: Mapping[str, Mapping[str, Sequence[str]]]):
        if AGENT in parts:
            raise ValueError(f"The part name {AGENT!r} is reserved for the agent's own mask")
        self.env = env.unwrapped
        model = self.env.mujoco_state[0]
        self.selections = {AGENT: agent_geoms(model)}
        for name, names in parts.items():
            unknown = set(names) - {"bodies", "geoms"}
            if unknown:
                raise ValueError(f"Part {name!r}: expected the keys 'bodies' and/or 'geoms', got {sorted(unknown)}")
            self.selections[name] = part_geoms(model, names.get("bodies", ()), names.get("geoms", ()))

    @property
    def names(self) -> list[str]:
        """``"agent"`` first, then the parts in the order given."""
        return list(self.selections)

    def __call__(self) -> dict[str, np.ndarray]:
        """``name -> (size, size)`` bool mask of the newest frame, from one segmentation render."""
        geom_ids = self.env.segmentation()
        return {name: part_mask(geom_ids, selection) for name, selection in self.selections.items()}
