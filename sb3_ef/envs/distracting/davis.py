"""DAVIS 2017 videos for the background distraction: video lists, folder checks, frame loading (docs/envs.md)."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from PIL import Image

from sb3_ef.envs.distracting.settings import DIFFICULTY_VIDEOS

#: The 60 DAVIS 2017 training videos, in the suite's order (a difficulty draws from the first n).
DAVIS_TRAIN_VIDEOS: tuple[str, ...] = (
    "bear", "bmx-bumps", "boat", "boxing-fisheye", "breakdance-flare", "bus", "car-turn", "cat-girl", "classic-car",
    "color-run", "crossing", "dance-jump", "dancing", "disc-jockey", "dog-agility", "dog-gooses", "dogs-scale",
    "drift-turn", "drone", "elephant", "flamingo", "hike", "hockey", "horsejump-low", "kid-football", "kite-walk",
    "koala", "lady-running", "lindy-hop", "longboard", "lucia", "mallard-fly", "mallard-water", "miami-surf",
    "motocross-bumps", "motorbike", "night-race", "paragliding", "planes-water", "rallye", "rhino", "rollerblade",
    "schoolgirls", "scooter-board", "scooter-gray", "sheep", "skate-park", "snowboard", "soccerball", "stroller",
    "stunt", "surf", "swing", "tennis", "tractor-sand", "train", "tuk-tuk", "upside-down", "varanus-cage", "walking",
)  # fmt: skip

#: The 30 DAVIS 2017 validation videos, in the suite's order.
DAVIS_VALIDATION_VIDEOS: tuple[str, ...] = (
    "bike-packing", "blackswan", "bmx-trees", "breakdance", "camel", "car-roundabout", "car-shadow", "cows",
    "dance-twirl", "dog", "dogs-jump", "drift-chicane", "drift-straight", "goat", "gold-fish", "horsejump-high",
    "india", "judo", "kite-surf", "lab-coat", "libby", "loading", "mbike-trick", "motocross-jump",
    "paragliding-launch", "parkour", "pigs", "scooter-black", "shooting", "soapbox",
)  # fmt: skip

VIDEO_LISTS: dict[str, tuple[str, ...]] = {"train": DAVIS_TRAIN_VIDEOS, "val": DAVIS_VALIDATION_VIDEOS}

DAVIS_DIR_VARIABLE = "SB3_EF_DAVIS_DIR"

DAVIS_DOWNLOAD_HINT = (
    "download DAVIS-2017-trainval-480p.zip (DAVIS 2017, TrainVal, 480p) from "
    "https://davischallenge.org/davis2017/code.html, unzip it, and pass its folder DAVIS/JPEGImages/480p as "
    f"background_dir (or set {DAVIS_DIR_VARIABLE} to it)"
)

_JPEG_SUFFIXES = (".jpg", ".jpeg")

#: Video folders whose frames all decoded, with each frame's name, size and modification time.
_DECODED: set[tuple[Path, tuple[tuple[str, int, int], ...]]] = set()


def frame_files(folder: Path) -> list[Path]:
    """The JPEG frames of a video folder in name order (DAVIS numbers them ``00000.jpg``, ...); ``[]`` if none."""
    if not folder.is_dir():
        return []
    return sorted(path for path in folder.iterdir() if path.suffix.lower() in _JPEG_SUFFIXES and path.is_file())


def video_names(videos: str | Sequence[str], difficulty: str) -> tuple[str, ...]:
    """The videos a difficulty draws from: the first 4 (easy), 8 (medium) or all (hard) of ``videos``."""
    if isinstance(videos, str) and videos in VIDEO_LISTS:
        names = VIDEO_LISTS[videos]
    elif not isinstance(videos, str) and videos and all(isinstance(name, str) and name for name in videos):
        names = tuple(videos)
    else:
        raise ValueError(f"background_videos must be 'train', 'val' or a list of DAVIS video names, got {videos!r}")
    count = DIFFICULTY_VIDEOS[difficulty]
    if count is not None and count > len(names):
        raise ValueError(
            f"The {difficulty!r} background difficulty draws from {count} videos, but background_videos names "
            f"{len(names)}: {list(names)}"
        )
    return names if count is None else names[:count]


def _nested_davis_folder(root: Path) -> Path | None:
    """The 480p folder inside ``root`` when the user passed one of its parents (``DAVIS``, ``JPEGImages``)."""
    for inner in ("JPEGImages/480p", "480p", "DAVIS/JPEGImages/480p"):
        if (root / inner).is_dir():
            return root / inner
    return None


def background_root(background_dir: str | os.PathLike[str] | None) -> Path:
    """The DAVIS frame folder: ``background_dir``, else ``$SB3_EF_DAVIS_DIR``; it must be an existing folder."""
    if background_dir is None:
        background_dir = os.environ.get(DAVIS_DIR_VARIABLE) or None
        if background_dir is None:
            raise ValueError(f"The 'background' distraction plays DAVIS 2017 videos: {DAVIS_DOWNLOAD_HINT}")
    if not isinstance(background_dir, (str, os.PathLike)):
        raise TypeError(f"background_dir must be a path (str or os.PathLike), got {type(background_dir).__name__}")
    root = Path(background_dir).expanduser()
    if not root.is_dir():
        raise FileNotFoundError(f"background_dir {str(root)!r} is not a folder: {DAVIS_DOWNLOAD_HINT}")
    return root


def video_folders(
    background_dir: str | os.PathLike[str] | None, videos: str | Sequence[str], difficulty: str
) -> tuple[Path, ...]:
    """The folders of the videos a background distraction draws from, each checked to hold frames that decode."""
    names = video_names(videos, difficulty)
    root = background_root(background_dir)
    missing = [name for name in names if not frame_files(root / name)]
    if len(missing) == len(names):
        nested = _nested_davis_folder(root)
        hint = f"pass {str(nested)!r} instead" if nested is not None else DAVIS_DOWNLOAD_HINT
        raise ValueError(
            f"background_dir {str(root)!r} holds no DAVIS videos (a folder of JPEG frames per video, such as "
            f"{names[0]}/00000.jpg): {hint}"
        )
    if missing:
        shown = ", ".join(missing[:5]) + (", ..." if len(missing) > 5 else "")
        raise ValueError(
            f"background_dir {str(root)!r} lacks {len(missing)} of the {len(names)} videos the {difficulty!r} "
            f"background draws from ({shown}): {DAVIS_DOWNLOAD_HINT}"
        )
    folders = tuple(root / name for name in names)
    check_frames(folders)
    return folders


def _frame_error(path: Path, error: OSError) -> ValueError:
    return ValueError(
        f"The background frame {str(path)!r} cannot be decoded ({error}): the file is damaged; unzip its video "
        "folder again from DAVIS-2017-trainval-480p.zip (https://davischallenge.org/davis2017/code.html)"
    )


def check_frames(folders: Sequence[Path]) -> None:
    """Decode every frame of ``folders`` (small), so that a damaged one is named when the env is made."""
    for folder in folders:
        files = frame_files(folder)
        signature = tuple((path.name, path.stat().st_size, path.stat().st_mtime_ns) for path in files)
        key = (folder.resolve(), signature)
        if key in _DECODED:
            continue
        for path in files:
            try:
                with Image.open(path) as image:
                    image.draft("RGB", (max(1, image.width // 8), max(1, image.height // 8)))
                    image.load()
            except OSError as error:  # PIL's UnidentifiedImageError and truncated files included
                raise _frame_error(path, error) from error
        _DECODED.add(key)


def load_textures(files: Sequence[Path], width: int, height: int) -> np.ndarray:
    """The frames as ``(len(files), height * width * 3)`` uint8 RGB textures, resized bilinearly to the texture."""
    textures = np.empty((len(files), height * width * 3), np.uint8)
    for index, path in enumerate(files):
        try:
            with Image.open(path) as image:
                resized = image.convert("RGB").resize((width, height), Image.Resampling.BILINEAR)
        except OSError as error:  # PIL's UnidentifiedImageError included
            raise _frame_error(path, error) from error
        textures[index] = np.asarray(resized, np.uint8).reshape(-1)
    return textures
