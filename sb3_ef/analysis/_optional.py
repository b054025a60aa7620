"""Lazy imports of the optional analysis dependencies with an error that names the extra to install."""

from __future__ import annotations

import importlib
from types import ModuleType


def require(module: str) -> ModuleType:
    """Import ``module`` or raise an ImportError telling the user to install ``sb3-ef[analysis]``."""
    try:
        return importlib.import_module(module)
    except ImportError as error:
        raise ImportError(
            f"sb3_ef.analysis needs '{module.split('.')[0]}' for this; install it with: pip install sb3-ef[analysis]"
        ) from error


def pyplot() -> ModuleType:
    """matplotlib.pyplot on the non-interactive Agg backend (files only, works headless)."""
    matplotlib = require("matplotlib")
    matplotlib.use("Agg")
    return require("matplotlib.pyplot")
