"""TFRecord shards as a source of episodes (BAIR's, RLDS / TFDS): records indexed on open, each read and decoded
with errors that name the file and the episode."""

from __future__ import annotations

import os
import warnings
from collections.abc import Sequence

from sb3_ef.offline.episodes import EpisodeError
from sb3_ef.offline.tfrecord import Features, parse_example, read_record_at, record_offsets


def index_records(paths: Sequence[str]) -> list[tuple[str, int]]:
    """``(path, byte offset)`` of every record of the shards ``paths``, in order; damaged, truncated or only empty
    shards raise ``EpisodeError``, an empty shard among others is named in a warning."""
    records, empty = [], []
    for path in paths:
        try:
            offsets = record_offsets(path)
        except ValueError as error:
            raise EpisodeError(str(error)) from error
        if not offsets:
            empty.append(path)
        records += [(path, offset) for offset in offsets]
    if not records:
        raise EpisodeError(
            f"No records in {list(paths)}: {len(empty)} of {len(paths)} TFRecord files are empty (0 bytes: an "
            "unfinished download or copy?)"
        )
    if empty:
        warnings.warn(f"Empty TFRecord files (0 bytes, no episode) skipped: {empty}", stacklevel=3)
    return records


def read_example(path: str, offset: int, source: str, verify: bool = True) -> Features:
    """The ``tf.train.Example`` of the record at ``offset`` of ``path``, its CRCs checked when ``verify``; errors
    name ``source`` (file and episode)."""
    with open(path, "rb") as file:
        try:
            data = read_record_at(file, offset, path, verify)
        except ValueError as error:
            raise EpisodeError(f"{source}: {error}") from error
    try:
        return parse_example(data)
    except ValueError as error:
        raise EpisodeError(f"{source}: {error}") from error


def shard_paths(paths: str | os.PathLike | Sequence[str | os.PathLike]) -> list[str]:
    """``paths`` as a list of strings (one path, or several)."""
    return [os.fspath(path) for path in ([paths] if isinstance(paths, (str, os.PathLike)) else paths)]
