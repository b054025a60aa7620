"""Masks of named bodies / geoms: the selection rule on a hand-written model, and on real Meta-World frames the
mask is exactly where the named part is drawn."""

import mujoco
import numpy as np
import pytest
from geom_masks import AGENT, PartMasks, part_geoms, part_mask

from sb3_ef.envs import make_env
from sb3_ef.envs.meta_world import FLIPPED_CAMERAS
from sb3_ef.envs.renderer import FrameRenderer

TREE = """
<mujoco>
  <worldbody>
    <geom name="floor" type="plane" size="1 1 0.1"/>
    <body name="tool">
      <freejoint/>
      <geom name="handle" type="capsule" fromto="0 0 0 0.2 0 0" size="0.01"/>
      <body name="head" pos="0.2 0 0">
        <geom name="head_a" type="box" size="0.02 0.02 0.02"/>
        <geom name="head_b" type="sphere" size="0.01"/>
      </body>
    </body>
    <body name="other" pos="0.5 0 0">
      <geom name="other_geom" type="sphere" size="0.05"/>
    </body>
  </worldbody>
</mujoco>
"""


def _names(model: mujoco.MjModel, selection: np.ndarray) -> set[str]:
    return {model.geom(index).name for index in np.flatnonzero(selection)}


def test_a_body_selects_its_whole_subtree_and_geoms_add_to_it():
    model = mujoco.MjModel.from_xml_string(TREE)
    assert _names(model, part_geoms(model, bodies=["tool"])) == {"handle", "head_a", "head_b"}
    assert _names(model, part_geoms(model, bodies=["head"])) == {"head_a", "head_b"}
    assert _names(model, part_geoms(model, bodies=["head"], geoms=["other_geom"])) == {
        "head_a",
        "head_b",
        "other_geom",
    }
    assert _names(model, part_geoms(model, geoms=["floor"])) == {"floor"}


def test_bad_names_are_refused_with_the_valid_ones():
    model = mujoco.MjModel.from_xml_string(TREE)
    with pytest.raises(ValueError, match=r"No body named 'hammer'.*'tool'"):
        part_geoms(model, bodies=["hammer"])
    with pytest.raises(ValueError, match="No geom named"):
        part_geoms(model, geoms=["nope"])
    with pytest.raises(TypeError, match="sequence of body names"):
        part_geoms(model, bodies="tool")
    with pytest.raises(ValueError, match="at least one"):
        part_geoms(model)


def test_part_mask_looks_segmentation_ids_up():
    selection = np.array([False, True, False])
    ids = np.array([[-1, 0], [1, 2]])
    np.testing.assert_array_equal(part_mask(ids, selection), [[False, False], [True, False]])
    with pytest.raises(ValueError, match=r"\[-1, 2\]"):
        part_mask(np.array([[3]]), selection)


@pytest.mark.parametrize(("task", "body"), [("hammer", "hammerbody"), ("door-open", "door_link")])
def test_part_mask_is_where_the_part_is_drawn(task, body):
    """Hiding the part's geoms (alpha 0) changes exactly the pixels of its mask; the agent mask is unchanged."""
    env = make_env(f"metaworld/{task}", size=64, frame_stack=1, fast_render=True, seed=0)
    try:
        observation, _ = env.reset(seed=0)
        masks = PartMasks(env, {"part": {"bodies": [body]}})
        assert masks.names == [AGENT, "part"]
        current = masks()
        np.testing.assert_array_equal(current[AGENT], env.unwrapped.agent_mask())
        assert current["part"].sum() >= 20 and not (current["part"] & current[AGENT]).any()

        model, data = env.unwrapped.mujoco_state
        camera = env.unwrapped.camera
        renderer = FrameRenderer(model, 64, camera, fast=True, flip=model.camera(camera).name in FLIPPED_CAMERAS)
        shown = renderer.rgb(data)
        np.testing.assert_array_equal(shown, observation.transpose(1, 2, 0))
        colours = model.geom_rgba.copy()
        model.geom_rgba[masks.selections["part"], 3] = 0.0
        hidden = renderer.rgb(data)
        model.geom_rgba[:] = colours
        renderer.close()
        changed = (shown != hidden).any(axis=-1)
        assert not (changed & ~current["part"]).any()  # nothing outside the mask is the part
        # Inside it, all but a few pixels change (where the part's colour equals what lies behind it).
        assert changed[current["part"]].mean() > 0.9
    finally:
        env.close()


def test_reserved_and_malformed_parts_are_refused():
    env = make_env("metaworld/hammer", size=32, frame_stack=1, fast_render=True, seed=0)
    try:
        with pytest.raises(ValueError, match="reserved"):
            PartMasks(env, {AGENT: {"bodies": ["hammerbody"]}})
        with pytest.raises(ValueError, match="'bodies' and/or 'geoms'"):
            PartMasks(env, {"hammer": {"body": ["hammerbody"]}})
    finally:
        env.close()
