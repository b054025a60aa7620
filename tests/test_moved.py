"""Importing a module or name that moved or left the package in the last release says where it went."""

from __future__ import annotations

import importlib
import re
import subprocess
import sys
from pathlib import Path

import pytest

from sb3_ef._moved import MOVED_MODULES, MOVED_NAMES

REPO = Path(__file__).parents[1]


@pytest.mark.parametrize("path", list(MOVED_MODULES))
def test_an_old_module_says_where_it_went(path):
    parent, _, name = path.rpartition(".")
    for statement in (f"import {path}", f"from {parent} import {name}"):
        with pytest.raises(ImportError, match=re.escape(f"{path} {MOVED_MODULES[path]}")):
            exec(statement, {})


@pytest.mark.parametrize("path", list(MOVED_NAMES))
def test_an_old_name_says_where_it_went_and_the_module_keeps_the_others(path):
    module, _, name = path.rpartition(".")
    with pytest.raises(ImportError, match=re.escape(f"{path} {MOVED_NAMES[path]}")):
        exec(f"from {module} import {name}", {})
    assert not hasattr(importlib.import_module(module), "no_such_name")


def resolves(dotted: str) -> bool:
    """Whether ``dotted`` is a module or a module's attribute."""
    try:
        importlib.import_module(dotted)
    except ImportError:
        module, _, name = dotted.rpartition(".")
        return hasattr(importlib.import_module(module), name)
    return True


@pytest.mark.parametrize("where", [*MOVED_MODULES.values(), *MOVED_NAMES.values()])
def test_every_new_place_exists(where):
    for file in re.findall(r"\b((?:experiments|benchmarks|tests)/\S+\.py)\b", where):
        assert (REPO / file).is_file(), file
    for dotted in re.findall(r"\b(sb3_ef(?:\.\w+)+)", where):
        assert resolves(dotted), dotted


def test_the_old_paths_answer_in_a_fresh_interpreter():
    """The finder is in place before the package's own modules load (they are imported by ``import sb3_ef``)."""
    code = "from sb3_ef.common.augmentation import augment_frames"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert "ImportError: sb3_ef.common.augmentation.augment_frames moved to sb3_ef.common.buffers.shifted" in (
        result.stderr
    )
