"""RLDS / TFDS episode shards (Open X-Embodiment) read without TensorFlow; see docs/offline.md."""

from __future__ import annotations

import glob
import os
import re
from collections.abc import Sequence

import numpy as np

from sb3_ef.offline.dataset import check_image_size, decode_image
from sb3_ef.offline.episodes import Episode, EpisodeError, make_episode
from sb3_ef.offline.tfrecord import ExampleShards, Features

STEPS = "steps/"
SHARD_PATTERN = re.compile(r".+\.tfrecord(-\d{5}-of-\d{5})?$")
#: Image and action features (without ``steps/``) of common Open X-Embodiment datasets; action parts concatenated.
_EEF = ("action/world_vector", "action/rotation_delta", "action/gripper_closedness_action")
_EEF_OPEN = ("action/world_vector", "action/rotation_delta", "action/open_gripper")
OXE_LAYOUTS: dict[str, tuple[str, tuple[str, ...]]] = {
    "fractal20220817_data": ("observation/image", _EEF),
    "kuka": ("observation/image", _EEF),
    "bridge": ("observation/image", _EEF_OPEN),
    "taco_play": ("observation/rgb_static", ("action/rel_actions_world",)),
    "jaco_play": ("observation/image", ("action/world_vector", "action/gripper_closedness_action")),
    "berkeley_autolab_ur5": ("observation/image", _EEF),
    "roboturk": ("observation/front_rgb", _EEF),
    "viola": ("observation/agentview_rgb", _EEF),
    "toto": ("observation/image", _EEF_OPEN),
    "language_table": ("observation/rgb", ("action",)),
    "droid": ("observation/exterior_image_1_left", ("action",)),
    "droid_cartesian": (
        "observation/exterior_image_1_left",
        ("action_dict/cartesian_velocity", "1-action_dict/gripper_position"),
    ),
}
#: ``1-<feature>`` is one minus it: DROID's gripper position (1 closed) as the openness Octo and OpenVLA train on.
ONE_MINUS = "1-"
#: Tried in turn when no layout is named.
_CAMERAS = ("image", "rgb", "image_0", "rgb_static", "agentview_rgb", "front_rgb", "exterior_image_1_left")
IMAGE_KEYS = tuple(f"observation/{camera}" for camera in _CAMERAS)
ACTION_PARTS = (*_EEF, "action/open_gripper")


def rlds_shards(path: str | os.PathLike, split: str = "train") -> list[str]:
    """The ``split`` shards of a TFDS folder (every TFRecord file when none is named after a split)."""
    path = os.fspath(path)
    if os.path.isfile(path):
        return [path]
    files = sorted(p for p in glob.glob(os.path.join(path, "*")) if SHARD_PATTERN.match(os.path.basename(p)))
    named = [p for p in files if f"-{split}.tfrecord" in os.path.basename(p)]
    return named or files


def is_rlds_folder(path: str | os.PathLike) -> bool:
    path = os.fspath(path)
    return os.path.isdir(path) and (
        os.path.isfile(os.path.join(path, "features.json")) or os.path.isfile(os.path.join(path, "dataset_info.json"))
    )


class RLDSDataset(ExampleShards):
    """Episodes of RLDS / TFDS TFRecord shards: one image feature and the action(s) of each step, decoded on access.

    :param paths: a TFDS dataset folder (``<name>/<version>``), or shard files.
    :param layout: an ``OXE_LAYOUTS`` name (default: the folder's dataset name when it is one, else auto-detected).
    :param image_key: the image feature (without ``steps/``); overrides ``layout``.
    :param action_keys: float features concatenated into the action (``"1-<feature>"``: one minus it).
    :param image_size: resize frames to ``image_size`` squared (None: keep their size).
    """

    def __init__(
        self,
        paths: str | os.PathLike | Sequence[str | os.PathLike],
        layout: str | None = None,
        image_key: str | None = None,
        action_keys: Sequence[str] | None = None,
        split: str = "train",
        image_size: int | None = None,
        verify: bool = True,
        min_frames: int = 2,
    ):
        if isinstance(paths, (str, os.PathLike)):
            shards, name = rlds_shards(paths, split), _dataset_name(os.fspath(paths))
        else:
            shards, name = [os.fspath(p) for p in paths], None
        if not shards:
            where = os.fspath(paths) if isinstance(paths, (str, os.PathLike)) else list(paths)
            raise FileNotFoundError(f"No TFRecord shards (<name>-{split}.tfrecord-*) in {where!r}")
        if layout is not None and layout not in OXE_LAYOUTS:
            raise ValueError(f"Unknown RLDS layout {layout!r}; known: {sorted(OXE_LAYOUTS)}")
        layout = layout or (name if name in OXE_LAYOUTS else None)
        default_image, default_actions = OXE_LAYOUTS[layout] if layout else (None, None)
        self.layout = layout
        self.image_key = image_key or default_image
        self.action_keys = tuple(action_keys) if action_keys else default_actions
        self.image_size = check_image_size(image_size)
        super().__init__(shards, verify, min_frames)

    def lengths(self) -> list[int]:
        """Frames per episode, from each record's step count (records are parsed, images not decoded)."""
        return [len(self._resolve(*self._example(i))[0]) for i in range(len(self))]

    def _resolve(self, features: Features, source: str) -> tuple[list[bytes], list[np.ndarray]]:
        """The image bytes of every step and the action feature arrays, by the configured or detected names."""
        available = sorted(key[len(STEPS) :] for key in features if key.startswith(STEPS))
        image_key = self.image_key or next((k for k in IMAGE_KEYS if STEPS + k in features), None)
        if image_key is None or STEPS + image_key not in features:
            raise EpisodeError(
                f"{source}: no image feature {image_key or IMAGE_KEYS[0]!r} in steps; the step features are "
                f"{available} (choose one with image_key=)"
            )
        images = features[STEPS + image_key]
        if not isinstance(images, list):
            raise EpisodeError(f"{source}: expected encoded images (bytes) in {image_key!r}, got numbers")
        action_keys = self.action_keys
        if action_keys is None:
            action_keys = (
                ("action",)
                if isinstance(features.get(STEPS + "action"), np.ndarray)
                else tuple(k for k in ACTION_PARTS if STEPS + k in features)
            )
        missing = [k for k in action_keys if STEPS + k.removeprefix(ONE_MINUS) not in features]
        if not action_keys or missing:
            raise EpisodeError(
                f"{source}: no action feature {missing or ['action']}; the step features are {available} "
                "(choose them with action_keys=)"
            )
        actions = []
        for key in action_keys:
            name = key.removeprefix(ONE_MINUS)
            values = features[STEPS + name]
            if isinstance(values, list) or len(values) % max(len(images), 1):
                raise EpisodeError(
                    f"{source}: expected {len(images)} steps x n numbers in {name!r}, got "
                    f"{len(values)} {'byte strings' if isinstance(values, list) else 'numbers'}"
                )
            action = np.asarray(values, dtype=np.float32).reshape(len(images), -1)
            actions.append(1 - action if key.startswith(ONE_MINUS) else action)
        return images, actions

    def _read(self, index: int) -> Episode:
        features, source = self._example(index)
        images, actions = self._resolve(features, source)
        for flag, position in (("is_first", 0), ("is_last", -1)):
            values = features.get(STEPS + flag)
            if isinstance(values, np.ndarray) and len(values) == len(images) and not values[position]:
                raise EpisodeError(f"{source}: expected steps/{flag} set on the {('first', 'last')[position]} step")
        frames = [
            decode_image(
                data, self.image_size, f"{source} step {step}: the image is not a JPEG / PNG ({len(data)} bytes)"
            )
            for step, data in enumerate(images)
        ]
        return make_episode(np.stack(frames), np.concatenate(actions, axis=1), None, source, self.min_frames)


def _dataset_name(path: str) -> str | None:
    """``fractal20220817_data`` of ``.../fractal20220817_data/0.1.0`` (the folder above a version folder)."""
    path = os.path.normpath(path)
    if os.path.isfile(path):
        return os.path.basename(path).split("-")[0]
    base = os.path.basename(path)
    return os.path.basename(os.path.dirname(path)) if re.fullmatch(r"\d+\.\d+\.\d+", base) else base
