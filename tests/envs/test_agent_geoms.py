"""The agent-geom rule on small hand-written models (no rendering)."""

import mujoco
import numpy as np

from sb3_ef.envs.agent_geoms import agent_geoms

ARM_AND_TARGET = """
<mujoco>
  <worldbody>
    <geom name="floor" type="plane" size="1 1 0.1"/>
    <body name="base">
      <geom name="pedestal" type="box" size="0.1 0.1 0.1"/>
      <body name="upper">
        <joint name="shoulder" type="hinge"/>
        <geom name="upper_geom" type="capsule" fromto="0 0 0 0.3 0 0" size="0.02"/>
        <body name="lower">
          <joint name="elbow" type="hinge"/>
          <geom name="lower_geom" type="capsule" fromto="0.3 0 0 0.6 0 0" size="0.02"/>
        </body>
      </body>
    </body>
    <body name="target" pos="0.5 0.5 0">
      <freejoint/>
      <geom name="target_geom" type="sphere" size="0.05"/>
    </body>
  </worldbody>
  <actuator>{actuator}</actuator>
</mujoco>
"""

MOCAP_WELD = """
<mujoco>
  <worldbody>
    <geom name="floor" type="plane" size="1 1 0.1"/>
    <body name="robot">
      <geom name="robot_base" type="box" size="0.1 0.1 0.1"/>
      <body name="hand" pos="0 0 0.3">
        <joint type="slide" axis="1 0 0"/>
        <geom name="hand_geom" type="sphere" size="0.05"/>
      </body>
    </body>
    <body name="handle" mocap="true" pos="0 0 0.3">
      <geom name="handle_geom" type="sphere" size="0.01" contype="0" conaffinity="0"/>
    </body>
    <body name="object" pos="0.4 0 0">
      <freejoint/>
      <geom name="object_geom" type="box" size="0.05 0.05 0.05"/>
    </body>
  </worldbody>
  <equality><weld body1="handle" body2="hand"/></equality>
</mujoco>
"""


def _agent_geom_names(xml: str) -> set[str]:
    model = mujoco.MjModel.from_xml_string(xml)
    mask = agent_geoms(model)
    assert mask.shape == (model.ngeom,) and mask.dtype == bool
    return {model.geom(index).name for index in np.flatnonzero(mask)}


def test_actuated_tree_is_the_agent_targets_and_world_are_not():
    xml = ARM_AND_TARGET.format(actuator='<motor joint="elbow"/>')
    assert _agent_geom_names(xml) == {"pedestal", "upper_geom", "lower_geom"}


def test_tendon_actuator_reaches_its_joints_tree():
    xml = ARM_AND_TARGET.format(actuator='<motor tendon="coupling"/>').replace(
        "<actuator>", '<tendon><fixed name="coupling"><joint joint="shoulder" coef="1"/></fixed></tendon><actuator>'
    )
    assert _agent_geom_names(xml) == {"pedestal", "upper_geom", "lower_geom"}


def test_without_actuators_nothing_is_the_agent():
    assert _agent_geom_names(ARM_AND_TARGET.format(actuator="")) == set()


def test_mocap_welded_tree_is_the_agent_but_not_the_mocap_handle():
    assert _agent_geom_names(MOCAP_WELD) == {"robot_base", "hand_geom"}
