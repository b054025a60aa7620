"""DAVIS 2017 videos for the background distraction: video lists, folder checks, frames decoded once into a
memory-mapped cache (docs/envs.md)."""

from __future__ import annotations

import fcntl
import hashlib
import json
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from PIL import Image

from sb3_ef.common.files import atomic_path
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

#: The decoded frames' folder, beside the video folders; where that cannot be written, one under the user's cache.
CACHE_FOLDER = ".sb3-ef-textures"
#: How a frame becomes a texture: part of every cache file's key, so that a change decodes the videos again.
TEXTURE_DECODING = "PIL RGB, bilinear resize to side x side, uint8 rows of side * side * 3"


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
    return tuple(root / name for name in names)


def _frame_error(path: Path, error: OSError) -> ValueError:
    return ValueError(
        f"The background frame {str(path)!r} cannot be decoded ({error}): the file is damaged; unzip its video "
        "folder again from DAVIS-2017-trainval-480p.zip (https://davischallenge.org/davis2017/code.html)"
    )


def load_textures(files: Sequence[Path], width: int, height: int, out: np.ndarray | None = None) -> np.ndarray:
    """The frames as ``(len(files), height * width * 3)`` uint8 RGB textures (into ``out`` if given), resized
    bilinearly to the texture."""
    textures = np.empty((len(files), height * width * 3), np.uint8) if out is None else out
    for index, path in enumerate(files):
        try:
            with Image.open(path) as image:
                resized = image.convert("RGB").resize((width, height), Image.Resampling.BILINEAR)
        except OSError as error:  # PIL's UnidentifiedImageError included
            raise _frame_error(path, error) from error
        textures[index] = np.asarray(resized, np.uint8).reshape(-1)
    return textures


def _cache_folders(root: Path) -> tuple[Path, Path]:
    """Where decoded videos of ``root`` are kept: beside them, else under ``$XDG_CACHE_HOME`` (``~/.cache``)."""
    user_cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return root / CACHE_FOLDER, user_cache / "sb3-ef" / "backgrounds"


def video_textures(folder: Path, side: int) -> np.ndarray:
    """A video's frames as ``(frames, side * side * 3)`` uint8 textures, memory-mapped from a cache file decoded once
    (naming a damaged frame) and shared by every process; its key: the frames' names, sizes and modification times,
    ``side`` and :data:`TEXTURE_DECODING`."""
    files = frame_files(folder)
    frames = [(path.name, path.stat().st_size, path.stat().st_mtime_ns) for path in files]
    key = hashlib.sha256(json.dumps([TEXTURE_DECODING, side, frames]).encode()).hexdigest()[:16]
    name = f"{folder.name}-{side}-{key}.npy"
    found = next((cache / name for cache in _cache_folders(folder.parent) if (cache / name).is_file()), None)
    return np.load(found or _decode_into_cache(files, side, folder.parent, name), mmap_mode="r")


def _decode_into_cache(files: Sequence[Path], side: int, root: Path, name: str) -> Path:
    """Decode ``files`` into the cache file ``name`` (atomically; one process at a time, the others wait for it)."""
    cache = _writable_cache(root)
    path = cache / name
    with open(cache / "lock", "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not path.is_file():
            with atomic_path(path) as temporary:
                shape = (len(files), side * side * 3)
                textures = np.lib.format.open_memmap(temporary, mode="w+", dtype=np.uint8, shape=shape)
                load_textures(files, side, side, out=textures)
                textures.flush()
    return path


def _writable_cache(root: Path) -> Path:
    """The first of :func:`_cache_folders` that can be written (made if missing)."""
    for cache in _cache_folders(root):
        try:
            cache.mkdir(parents=True, exist_ok=True)
        except OSError:
            continue
        if os.access(cache, os.W_OK):
            return cache
    raise PermissionError(
        f"Decoded background frames are kept in {' or '.join(map(str, _cache_folders(root)))}, and neither can be "
        "written: make one writable, or set XDG_CACHE_HOME to a writable folder"
    )
