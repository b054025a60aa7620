"""The zip of a saved ``DreamerV3``, handled as SB3 handles its own."""

from __future__ import annotations

import io
import json
import os
import zipfile
from pathlib import Path
from typing import IO, Any

from sb3_ef.common.saved_models import save_model_atomically

#: The entries of the zip: the settings (``data``, where SB3 keeps its own), sheeprl's configuration, the weights.
DATA, CONFIG, WEIGHTS = "data", "config.yaml", "checkpoint.ckpt"
ENTRIES = (DATA, CONFIG, WEIGHTS)

PathOrFile = str | os.PathLike | IO[bytes] | io.BufferedIOBase


def write_model(path: PathOrFile, info: dict[str, Any], config: str, weights: bytes) -> None:
    """Write the three entries to ``path`` (whole or not at all) or into an open binary file."""

    def write(file: Any) -> None:
        with zipfile.ZipFile(file, "w") as archive:
            archive.writestr(DATA, json.dumps(info, indent=1))
            archive.writestr(CONFIG, config)
            archive.writestr(WEIGHTS, weights)

    save_model_atomically(lambda file, *_: write(file), path)  # type: ignore[arg-type]


def read_model(path: PathOrFile) -> tuple[dict[str, Any], bytes, bytes]:
    """The settings, sheeprl configuration and weights that :func:`write_model` wrote."""
    source: Any = path
    if isinstance(path, (str, os.PathLike)):
        given = Path(path)
        source = given if given.is_file() else given.with_name(f"{given.name}.zip")
        if not source.is_file():
            raise FileNotFoundError(f"No saved DreamerV3 model at {str(path)!r} (nor at {str(source)!r})")
    try:
        with zipfile.ZipFile(source) as archive:
            names = set(archive.namelist())
            saved = json.loads(archive.read(DATA)).get("algorithm") if DATA in names else None
            if saved is not None and saved != "DreamerV3":
                raise ValueError(f"Cannot load {path} as DreamerV3: it was saved by {saved}, use {saved}.load")
            if not set(ENTRIES) <= names or archive.testzip() is not None:
                raise ValueError(
                    f"{path} is not a DreamerV3 model: expected the files {list(ENTRIES)} of DreamerV3.save(), got "
                    f"{sorted(names)}"
                )
            info = json.loads(archive.read(DATA))
            return info, archive.read(CONFIG), archive.read(WEIGHTS)
    except (zipfile.BadZipFile, EOFError, json.JSONDecodeError) as error:
        raise ValueError(f"{path} is not a DreamerV3 model: not a complete zip archive ({error})") from error
