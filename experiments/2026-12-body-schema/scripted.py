"""Scripted Meta-World episodes for the body-schema measurements: a held tool, a door under the gripper, a
distractor that moves on its own.

Every episode starts with a few agent steps of zero action (:data:`SETTLE_STEPS`) and then has two phases. An
optional *prefix* drives the robot with Meta-World's scripted policy for the task
(``metaworld.policies``) until a condition holds (the hammer is lifted in the gripper, the door has started to
open); it is not recorded. Then the robot *babbles* for ``steps`` agent steps and that phase is recorded: each of
the three position components is -1 or +1 at random (the paper's sign babbling) and the gripper component is held
at +1 (closed), so a grasped tool stays in the hand. With a distractor, before every agent step the object is moved
by a random step on the table (a random walk independent of the actions, its velocity zeroed).

Scenarios (:data:`SCENARIOS`):

- ``hammer-held``: the scripted hammer policy grasps and lifts the hammer, then the robot babbles holding it.
- ``hammer-table``: the robot babbles from its start pose, the hammer lies on the table.
- ``door-handle``: the scripted door-open policy puts the gripper on the handle and starts pulling, then the robot
  babbles from there (the door moves only where the gripper pushes or pulls it).
- ``hammer-distractor``: the robot babbles from its start pose while the hammer walks on the table by itself.

Recorded per frame: the frame, the masks of the agent and of the scenario's object (:mod:`geom_masks`),
the hand and object positions (Meta-World's state vector) and whether the object is *attached*: its offset from
the hand is within ``attach_tolerance`` of the offset at the first recorded frame. An episode is a deterministic
function of (scenario, seed, index): the env is reset with ``seed + index`` and the babbling draws from a
generator seeded with ``(seed, index)``.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np
from geom_masks import AGENT, PartMasks

from sb3_ef.analysis.prediction import figure_eight_actions
from sb3_ef.common.env_checks import FRAME_CHANNELS
from sb3_ef.envs import make_env


@dataclass(frozen=True)
class Scenario:
    """How one kind of scripted episode is made.

    :param task: Meta-World task name.
    :param part: name of the measured object and its bodies (:class:`~geom_masks.PartMasks` format).
    :param prefix: scripted-policy class name in ``metaworld.policies`` run before babbling, or None.
    :param prefix_done: ``(state, start_state) -> bool`` on Meta-World's state vector: when the prefix ends.
    :param distractor_step: metres per agent step of the object's random walk (0: no distractor).
    """

    task: str
    part: tuple[str, tuple[str, ...]]
    prefix: str | None = None
    prefix_done: Callable[[np.ndarray, np.ndarray], bool] | None = None
    distractor_step: float = 0.0


def _hammer_lifted(state: np.ndarray, start: np.ndarray) -> bool:
    return bool(state[6] > start[6] + 0.06)


def _door_opening(state: np.ndarray, start: np.ndarray) -> bool:
    return bool(np.linalg.norm(state[4:7] - start[4:7]) > 0.05)


SCENARIOS: dict[str, Scenario] = {
    "hammer-held": Scenario("hammer", ("hammer", ("hammerbody",)), "SawyerHammerV3Policy", _hammer_lifted),
    "hammer-table": Scenario("hammer", ("hammer", ("hammerbody",))),
    "door-handle": Scenario("door-open", ("door", ("door_link",)), "SawyerDoorOpenV3Policy", _door_opening),
    "hammer-distractor": Scenario("hammer", ("hammer", ("hammerbody",)), distractor_step=0.01),
}

#: Agent steps with a zero action after every reset: Meta-World places objects slightly inside the table and they
#: pop up during the first steps.
SETTLE_STEPS = 5
#: Agent steps the scripted prefix may take before the episode's seed is given up for the next one.
PREFIX_LIMIT = 60
#: Half-width (metres) of the box around its start position in which a distractor walks.
DISTRACTOR_RANGE = 0.12


@dataclass(frozen=True)
class ScriptedEpisode:
    """One recorded babbling phase: ``frames`` uint8 (T + 1, 3, s, s), ``actions`` float32 (T, 4), ``masks``
    name -> bool (T + 1, s, s) (``"agent"`` and the scenario's object), ``hand`` / ``object`` positions (T + 1, 3),
    ``attached`` bool (T + 1,), and the reset seed actually used."""

    scenario: str
    frames: np.ndarray
    actions: np.ndarray
    masks: dict[str, np.ndarray]
    hand: np.ndarray
    object: np.ndarray
    attached: np.ndarray
    reset_seed: int


class ScriptedCollector:
    """Records :class:`ScriptedEpisode` s of one scenario from one env (kept open between episodes).

    :param scenario: a key of :data:`SCENARIOS`.
    :param size: frame size; ``action_repeat`` simulator steps per agent step; ``fast_render`` as in ``make_env``.
    :param attach_tolerance: metres the object's offset from the hand may drift and still count as attached.
    """

    def __init__(
        self,
        scenario: str,
        size: int = 64,
        action_repeat: int = 2,
        fast_render: bool = True,
        attach_tolerance: float = 0.02,
    ):
        if scenario not in SCENARIOS:
            raise ValueError(f"Unknown scenario {scenario!r}, expected one of {sorted(SCENARIOS)}")
        self.name, self.scenario = scenario, SCENARIOS[scenario]
        self.attach_tolerance = attach_tolerance
        self.env = make_env(
            f"metaworld/{self.scenario.task}",
            size=size,
            frame_stack=1,
            action_repeat=action_repeat,
            fast_render=fast_render,
        )
        part_name, bodies = self.scenario.part
        self.part = part_name
        self.masks = PartMasks(self.env, {part_name: {"bodies": bodies}})
        self.policy: Any = None  # Meta-World's scripted policy for the prefix (its classes are untyped)
        if self.scenario.prefix is not None:
            import metaworld.policies

            self.policy = getattr(metaworld.policies, self.scenario.prefix)()

    def close(self) -> None:
        self.env.close()

    def __enter__(self) -> ScriptedCollector:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def _state(self) -> np.ndarray:
        return self.env.unwrapped.state_observation()

    def _run_prefix(self, reset_seed: int) -> np.ndarray | None:
        """Reset and run the scripted policy until its condition holds: the newest frame, or None if the
        condition did not hold within :data:`PREFIX_LIMIT` steps."""
        observation, _ = self.env.reset(seed=reset_seed)
        for _ in range(SETTLE_STEPS):
            observation, *_ = self.env.step(np.zeros(self.env.action_space.shape, np.float32))
        if self.policy is None:
            return observation
        start = self._state()
        done = self.scenario.prefix_done
        assert done is not None, "a scenario with a scripted prefix says when it is done"
        for _ in range(PREFIX_LIMIT):
            with warnings.catch_warnings():  # metaworld warns that its own gains exceed the action bounds
                warnings.simplefilter("ignore", UserWarning)
                action = self.policy.get_action(self._state())
            observation, *_ = self.env.step(np.clip(action, -1.0, 1.0).astype(np.float32))
            if done(self._state(), start):
                return observation
        return None

    def _free_joint(self) -> tuple[int, int]:
        """qpos and qvel addresses of the object's free joint."""
        model = self.env.unwrapped.mujoco_state[0]
        body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, self.scenario.part[1][0])
        joint = model.body_jntadr[body]
        if joint < 0 or model.jnt_type[joint] != mujoco.mjtJoint.mjJNT_FREE:
            raise ValueError(f"{self.name}: a distractor needs a free joint on body {self.scenario.part[1][0]!r}")
        return int(model.jnt_qposadr[joint]), int(model.jnt_dofadr[joint])

    def _move_distractor(self, rng: np.random.Generator, home: np.ndarray) -> None:
        """One random step of the object's free joint on the table, velocity zeroed."""
        model, data = self.env.unwrapped.mujoco_state
        address, velocity = self._free_joint()
        position = data.qpos[address : address + 2] + self.scenario.distractor_step * rng.choice([-1.0, 1.0], 2)
        data.qpos[address : address + 2] = np.clip(position, home - DISTRACTOR_RANGE, home + DISTRACTOR_RANGE)
        data.qvel[velocity : velocity + 6] = 0.0
        mujoco.mj_forward(model, data)

    def episode(self, seed: int, index: int, steps: int = 40, with_masks: bool = True) -> ScriptedEpisode:
        """Episode ``index`` of the scenario for ``seed``: ``steps`` babbling steps after the prefix.

        When the prefix fails for reset seed ``seed + index``, reset seeds ``seed + index + k * 100_003`` are
        tried in turn (k = 1, 2, ...; at most 10).
        """
        for attempt in range(10):
            reset_seed = seed + index + attempt * 100_003
            observation = self._run_prefix(reset_seed)
            if observation is not None:
                break
        else:
            raise RuntimeError(f"{self.name}: the scripted prefix failed for 10 reset seeds from {seed + index}")
        rng = np.random.default_rng([seed, index])
        home = None
        if self.scenario.distractor_step:
            address, _ = self._free_joint()
            home = self.env.unwrapped.mujoco_state[1].qpos[address : address + 2].copy()
        frames: list[np.ndarray] = []
        actions: list[np.ndarray] = []
        masks: list[dict[str, np.ndarray]] = []
        states: list[np.ndarray] = []

        def record(observation: np.ndarray) -> None:
            frames.append(observation[-FRAME_CHANNELS:])
            states.append(self._state())
            if with_masks:
                masks.append(self.masks())

        record(observation)
        for _ in range(steps):
            if home is not None:
                self._move_distractor(rng, home)
            action = np.append(rng.choice([-1.0, 1.0], 3), 1.0).astype(np.float32)
            observation, *_ = self.env.step(action)
            actions.append(action)
            record(observation)
        trajectory = np.stack(states)
        hand, obj = trajectory[:, :3], trajectory[:, 4:7]
        offset = obj - hand
        attached = np.linalg.norm(offset - offset[0], axis=1) <= self.attach_tolerance
        names = [AGENT, self.part]
        return ScriptedEpisode(
            scenario=self.name,
            frames=np.stack(frames),
            actions=np.stack(actions),
            masks={name: np.stack([m[name] for m in masks]) for name in names} if with_masks else {},
            hand=hand,
            object=obj,
            attached=attached,
            reset_seed=reset_seed,
        )


def figure_eight_probe(steps: int, period: int | None = None) -> np.ndarray:
    """The figure-eight probe (:func:`~sb3_ef.analysis.prediction.figure_eight_actions`) in the babbling's
    convention: x and y velocities of a figure eight of ``period`` steps (default ``steps``), height 0, gripper
    closed (+1). Smooth values never seen in the sign babbling: (steps, 4) float32."""
    actions = figure_eight_actions(steps, 4, period=period or steps)
    actions[:, 2], actions[:, 3] = 0.0, 1.0
    return actions
