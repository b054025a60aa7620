"""Camera distraction: the camera moved and rolled within the suite's ranges (docs/envs.md), agent masks included."""

from __future__ import annotations

import mujoco
import numpy as np

from sb3_ef.envs.distracting.settings import CameraSettings

#: The agent's body whose subtree centre of mass the suite's camera follows (the first body below the world).
_AGENT_BODY = 1


def _spherical(position: np.ndarray) -> np.ndarray:
    """``(distance, azimuth, polar angle)`` of a Cartesian position."""
    horizontal = np.hypot(position[0], position[1])
    return np.array(
        [np.linalg.norm(position), np.arctan2(position[1], position[0]), np.arctan2(horizontal, position[2])]
    )


def _cartesian(sphere: np.ndarray) -> np.ndarray:
    distance, azimuth, polar = sphere
    return distance * np.array([np.sin(polar) * np.cos(azimuth), np.sin(polar) * np.sin(azimuth), np.cos(polar)])


def _axis_rotation(cos: float, sin: float, axis: np.ndarray) -> np.ndarray:
    """Rodrigues' rotation matrix about ``axis`` by the angle with cosine ``cos`` and sine ``sin``."""
    cross = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return cos * np.eye(3) + sin * cross + (1.0 - cos) * np.outer(axis, axis)


def _roll_rotation(angle: float) -> np.ndarray:
    return _axis_rotation(np.cos(angle), np.sin(angle), np.array([0.0, 0.0, 1.0]))


def _look_at_upright(target: np.ndarray, position: np.ndarray) -> np.ndarray:
    """Camera orientation looking from ``position`` at ``target`` without roll (a yaw and a pitch)."""
    direction = (target - position) / np.linalg.norm(target - position)
    yaw = np.arctan2(direction[0], direction[1])
    pitch = np.arctan2(direction[2], np.hypot(*direction[:2])) + np.pi / 2  # a camera looks along its -z axis
    cos_yaw, sin_yaw, cos_pitch, sin_pitch = np.cos(-yaw), np.sin(-yaw), np.cos(pitch), np.sin(pitch)
    yaw_matrix = np.array([[cos_yaw, -sin_yaw, 0.0], [sin_yaw, cos_yaw, 0.0], [0.0, 0.0, 1.0]])
    pitch_matrix = np.array([[1.0, 0.0, 0.0], [0.0, cos_pitch, -sin_pitch], [0.0, sin_pitch, cos_pitch]])
    return yaw_matrix @ pitch_matrix


def _look_at(target: np.ndarray, position: np.ndarray) -> np.ndarray:
    """Orientation looking from ``position`` at ``target`` by the shortest rotation: smooth at the poles (reacher)."""
    direction = (target - position) / np.linalg.norm(target - position)
    axis = np.cross([0.0, 0.0, -1.0], direction)
    sin = float(np.linalg.norm(axis))
    return _axis_rotation(-direction[2], sin, axis / (sin + 1e-4))


def _look_at_point(data: mujoco.MjData, camera: int) -> np.ndarray:
    """The point on the camera's axis at the agent's distance from it."""
    distance = np.linalg.norm(data.cam_xpos[camera] - data.subtree_com[_AGENT_BODY])
    return data.cam_xmat[camera].reshape(3, 3) @ np.array([0.0, 0.0, -distance]) + data.cam_xpos[camera]


class CameraDistraction:
    """Moves one fixed or centre-of-mass tracking camera of a model within the ranges of ``settings``."""

    def __init__(self, model: mujoco.MjModel, camera: int, settings: CameraSettings) -> None:
        mode = mujoco.mjtCamLight(int(model.cam_mode[camera]))
        if mode not in (mujoco.mjtCamLight.mjCAMLIGHT_FIXED, mujoco.mjtCamLight.mjCAMLIGHT_TRACKCOM):
            raise ValueError(
                f"The camera distraction moves fixed or centre-of-mass tracking cameras; camera {camera} "
                f"({model.camera(camera).name!r}) is {mode.name}: choose another camera"
            )
        self.camera = camera
        self.settings = settings
        self._tracking = mode == mujoco.mjtCamLight.mjCAMLIGHT_TRACKCOM
        # Set by reset(): spherical bounds and position, Cartesian velocity.
        self._low, self._high, self._sphere = np.zeros(3), np.zeros(3), np.zeros(3)
        self._velocity, self._target = np.zeros(3), np.zeros(3)
        self._roll = self._roll_velocity = self._velocity_scale = 0.0

    def reset(self, model: mujoco.MjModel, data: mujoco.MjData, rng: np.random.Generator) -> None:
        """Ranges around the camera's pose in the new episode, a start pose and velocities drawn in them."""
        settings = self.settings
        self._target = _look_at_point(data, self.camera)
        start = data.cam_xpos[self.camera].copy()
        if self._tracking:
            start -= data.subtree_com[_AGENT_BODY]
        distance, azimuth, polar = _spherical(start)
        self._velocity_scale = distance / 4.0  # the suite's speeds are for cameras 4 units away
        low = np.array([distance * (1.0 - settings.max_zoom_in), azimuth, polar])
        high = np.array([distance * (1.0 + settings.max_zoom_out), azimuth, polar])
        low[1:] -= settings.horizontal_delta, settings.vertical_delta
        high[1:] += settings.horizontal_delta, settings.vertical_delta
        if settings.upper_quadrant:  # above the ground, on the front side (azimuth in [-pi, 0])
            low[1:] = max(low[1], -np.pi), max(low[2], 0.0)
            high[1:] = min(high[1], 0.0), min(high[2], np.pi / 2)
        self._low, self._high = low, high
        self._sphere = rng.uniform(low, high)
        self._roll = rng.uniform(-settings.roll_delta, settings.roll_delta)
        velocity = rng.standard_normal(3)
        self._velocity = velocity / np.linalg.norm(velocity) * rng.uniform(0.0, settings.max_velocity)
        self._roll_velocity = rng.uniform(-settings.max_roll_velocity, settings.max_roll_velocity)
        self.step(model, data, rng)

    def step(self, model: mujoco.MjModel, data: mujoco.MjData, rng: np.random.Generator) -> None:
        """One random-walk step of the velocities, the move, and the camera's new pose written to ``data``."""
        settings = self.settings
        self._velocity = self._velocity + rng.standard_normal(3) * settings.velocity_std * self._velocity_scale
        self._roll_velocity += rng.standard_normal() * settings.roll_std
        speed, limit = np.linalg.norm(self._velocity), settings.max_velocity * self._velocity_scale
        if speed > limit:
            self._velocity *= limit / speed
        max_roll = settings.max_roll_velocity
        self._roll_velocity = float(np.clip(self._roll_velocity, -max_roll, max_roll))
        position = _cartesian(self._sphere)
        self._sphere = np.clip(_spherical(position + self._velocity), self._low, self._high)
        self._velocity = _cartesian(self._sphere) - position
        roll = float(np.clip(self._roll + self._roll_velocity, -settings.roll_delta, settings.roll_delta))
        self._roll_velocity, self._roll = roll - self._roll, roll
        position = _cartesian(self._sphere)
        target = self._target
        if self._tracking:
            position = position + data.subtree_com[_AGENT_BODY]
            target = _look_at_point(data, self.camera)
        look = _look_at_upright(target, position) if settings.upper_quadrant else _look_at(target, position)
        data.cam_xpos[self.camera] = position
        data.cam_xmat[self.camera] = (look @ _roll_rotation(self._roll)).reshape(-1)
