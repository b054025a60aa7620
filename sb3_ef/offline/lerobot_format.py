"""The LeRobot dataset layout the reader and writer share: paths, column names and the packages that read them."""

from __future__ import annotations

import os
from typing import Any

INFO = os.path.join("meta", "info.json")
STATS = os.path.join("meta", "stats.json")
TASKS = os.path.join("meta", "tasks.parquet")
V3_DATA_PATH = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
V3_VIDEO_PATH = "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"
V3_EPISODES_PATH = "meta/episodes/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
VIDEO_COLUMNS = ("chunk_index", "file_index", "from_timestamp", "to_timestamp")
#: The Parquet column of the agent masks :class:`~sb3_ef.offline.lerobot_writer.LeRobotWriter` writes (sb3-ef's own).
MASK_KEY = "observation.agent_mask"


def is_lerobot_dataset(path: str | os.PathLike) -> bool:
    return os.path.isfile(os.path.join(os.fspath(path), INFO))


def lerobot_imports() -> tuple[Any, Any]:
    """PyAV and ``pyarrow.parquet``, or an ImportError naming the extra that installs them."""
    try:
        import av
        import pyarrow.parquet as pq
    except ImportError as error:
        raise ImportError("LeRobot datasets need pyarrow and av (PyAV): pip install sb3-ef[offline]") from error
    return av, pq
