"""Saved model files: written atomically, and which algorithm saved one (no torch import, for the command line)."""

from __future__ import annotations

import io
import json
import os
import zipfile
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import IO, Any

from sb3_ef import registry
from sb3_ef.common.files import write_atomically

#: Module of a saved policy class -> the sb3-ef algorithms whose files hold it (the registry's policy modules).
POLICY_OWNERS = {
    module: " or ".join(item.class_name for item in registry.ALGORITHMS.values() if item.legacy_policy_module == module)
    for module in dict.fromkeys(item.legacy_policy_module for item in registry.ALGORITHMS.values())
    if module is not None
}
#: Attributes only the model files of sb3-ef 0.1.0's Ego-Foresight variants hold.
LEGACY_EF_ATTRIBUTES = ("ef_horizon", "_ef_generator", "ef_learning_rate")


def model_zip_path(path: str | os.PathLike) -> Path:
    """Where SB3's ``save`` writes ``path``: as given when it has a suffix, else with ``.zip`` added."""
    path = Path(path)
    return path if path.suffix else path.with_name(f"{path.name}.zip")


def save_model_atomically(
    save: Callable[..., None],
    path: str | os.PathLike | io.BufferedIOBase,
    exclude: Iterable[str] | None = None,
    include: Iterable[str] | None = None,
) -> None:
    """SB3's ``save`` (e.g. ``super().save``) written atomically to :func:`model_zip_path`."""
    if not isinstance(path, (str, os.PathLike)):
        save(path, exclude, include)
        return
    target = model_zip_path(path)
    if target.is_dir():
        raise IsADirectoryError(f"Cannot save the model to {str(path)!r}: it is a folder (give a file path)")
    target.parent.mkdir(parents=True, exist_ok=True)
    write_atomically(target, lambda file: save(file, exclude, include))  # a file SB3 leaves open on an error


def saved_data(path: str | os.PathLike | IO[bytes] | io.BufferedIOBase) -> dict[str, Any] | None:
    """The JSON ``data`` of a model zip (path or file object), or ``None`` when unreadable (SB3's load reports why)."""
    if isinstance(path, (str, os.PathLike)):
        given = Path(path)
        path = given if given.suffix == ".zip" or given.is_file() else given.with_name(f"{given.name}.zip")
        opened: IO[bytes] | io.BufferedIOBase | None = None
    else:
        opened = path
    position = opened.tell() if opened is not None else 0
    try:
        with zipfile.ZipFile(opened if opened is not None else path) as archive:
            data = json.loads(archive.read("data"))
    except (zipfile.BadZipFile, KeyError, ValueError, OSError):
        return None
    finally:
        if opened is not None:
            opened.seek(position)
    return data if isinstance(data, dict) else None


def saved_algorithm(data: dict[str, Any] | None) -> str | None:
    """The class name of the algorithm that saved ``data`` (``None`` when the file records none)."""
    name = (data or {}).get("algorithm")
    return name if isinstance(name, str) else None


def is_legacy(data: dict[str, Any]) -> bool:
    """Whether ``data`` is that of a file saved by sb3-ef 0.1.0 (no ``algorithm`` entry)."""
    if "algorithm" in data:
        return False
    module = (data.get("policy_class") or {}).get("__module__", "")
    return module.startswith("sb3_ef.") or any(data.get(name) is not None for name in LEGACY_EF_ATTRIBUTES)


def check_saved_model(algo_class: type, where: Any, data: dict[str, Any] | None) -> None:
    """Raise ``ValueError`` saying what to do when ``algo_class`` cannot load the model whose ``data`` is given."""
    if data is None:
        return
    name = algo_class.__name__
    if isinstance(where, io.IOBase):
        where = "the file"
    saved = saved_algorithm(data)
    if saved is not None:
        if saved != name:
            raise ValueError(f"Cannot load {where} as {name}: it was saved by {saved}, use {saved}.load")
        return
    if is_legacy(data):
        raise ValueError(
            f"{where} was saved by sb3-ef 0.1.0, whose files this version reads after a one-time conversion: run "
            f"`sb3-ef upgrade {where} NEW.zip`, then load NEW.zip with {name}.load"
        )
    module = (data.get("policy_class") or {}).get("__module__")
    expected = {policy.__module__ for policy in getattr(algo_class, "policy_aliases", {}).values()}
    if module in POLICY_OWNERS and expected and module not in expected:  # a user's own policy class is let through
        owner = POLICY_OWNERS[module]
        raise ValueError(f"{where} was saved by {owner}, not {name}: load it with {owner}")
    if module in POLICY_OWNERS and module.startswith(("stable_baselines3.", "sb3_contrib.")):
        plain = module.split(".")[1].upper()
        raise ValueError(
            f"{where} was saved by {'sb3-contrib' if module.startswith('sb3_contrib') else 'SB3'}'s own {plain}, "
            f"without {name}'s auxiliary loss: load it with {plain}.load"
        )
