"""Which geoms of a MuJoCo model belong to the agent's own body, by one rule for every suite: the kinematic trees
(off the world body) holding a body that an actuator moves or that is welded to a mocap body (Meta-World's arm)."""

from __future__ import annotations

import mujoco
import numpy as np


def _tendon_bodies(model: mujoco.MjModel, tendon: int) -> list[int]:
    """Bodies a tendon acts on: those of its joints and sites."""
    bodies = []
    start = model.tendon_adr[tendon]
    for wrap in range(start, start + model.tendon_num[tendon]):
        kind, obj = model.wrap_type[wrap], model.wrap_objid[wrap]
        if kind == mujoco.mjtWrap.mjWRAP_JOINT:
            bodies.append(int(model.jnt_bodyid[obj]))
        elif kind == mujoco.mjtWrap.mjWRAP_SITE:
            bodies.append(int(model.site_bodyid[obj]))
    return bodies


def driven_bodies(model: mujoco.MjModel) -> set[int]:
    """Bodies moved directly by an actuator or welded to a mocap body."""
    trn = mujoco.mjtTrn
    bodies: set[int] = set()
    for actuator in range(model.nu):
        kind, target = model.actuator_trntype[actuator], int(model.actuator_trnid[actuator, 0])
        if kind in (trn.mjTRN_JOINT, trn.mjTRN_JOINTINPARENT):
            bodies.add(int(model.jnt_bodyid[target]))
        elif kind == trn.mjTRN_TENDON:
            bodies.update(_tendon_bodies(model, target))
        elif kind == trn.mjTRN_SITE:
            bodies.add(int(model.site_bodyid[target]))
        elif kind == trn.mjTRN_BODY:
            bodies.add(target)
    for constraint in range(model.neq):
        if (
            model.eq_type[constraint] != mujoco.mjtEq.mjEQ_WELD
            or model.eq_objtype[constraint] != mujoco.mjtObj.mjOBJ_BODY
        ):
            continue
        first, second = int(model.eq_obj1id[constraint]), int(model.eq_obj2id[constraint])
        if model.body_mocapid[first] >= 0:
            bodies.add(second)
        elif model.body_mocapid[second] >= 0:
            bodies.add(first)
    return bodies


def agent_geoms(model: mujoco.MjModel) -> np.ndarray:
    """Boolean array of shape ``(model.ngeom,)``: true for the geoms of the agent's body (rule in the module doc)."""
    roots = {int(model.body_rootid[body]) for body in driven_bodies(model)}
    roots.discard(0)
    agent_bodies = np.isin(model.body_rootid, sorted(roots)) & (model.body_mocapid < 0)
    return agent_bodies[model.geom_bodyid]
