"""The algorithm registry: the library's root exports its library classes, and every key reaches each workbench
command through the hook its package keeps for it or through that package's default."""

from __future__ import annotations

import pytest

import sb3_ef
from sb3_ef import registry
from sb3_ef.grid.checks import GRID_CHECKS
from sb3_ef.grid.run import GRID_RUNS
from sb3_ef.registry import import_target
from sb3_ef.zoo.config import OWN_LOOPS


@pytest.mark.parametrize("key", [key for key, item in registry.ALGORITHMS.items() if not item.workbench])
def test_the_root_exports_each_library_class(key):
    item = registry.ALGORITHMS[key]
    assert item.class_name in sb3_ef.__all__
    assert getattr(sb3_ef, item.class_name) is item.algorithm_class


def test_the_root_refuses_a_workbench_class_with_the_import_that_gives_it():
    with pytest.raises(ImportError, match=r"`from sb3_ef\.dreamerv3 import DreamerV3`"):
        from sb3_ef import DreamerV3  # noqa: F401
    assert "DreamerV3" not in sb3_ef.__all__


def test_every_key_has_its_hook_or_the_default_and_every_hook_a_key():
    """The grid's and the zoo's per-key tables name known keys and importable functions; every other key takes the
    default: the grid trains it with SB3's ``learn`` and checks it as such, rl-zoo3 trains it."""
    from sb3_ef.zoo.registration import algorithm_classes

    tables = {"OWN_LOOPS": OWN_LOOPS, "GRID_RUNS": GRID_RUNS, "GRID_CHECKS": GRID_CHECKS}
    unknown = {name: sorted(set(table) - set(registry.ALGORITHMS)) for name, table in tables.items()}
    assert unknown == {name: [] for name in tables}
    paths = [*GRID_RUNS.values(), *GRID_CHECKS.values(), *(path for pair in OWN_LOOPS.values() for path in pair)]
    assert all(callable(import_target(path)) for path in paths)
    zoo_trained = algorithm_classes()
    assert [key for key in registry.ALGORITHMS if (key in OWN_LOOPS) == (key in zoo_trained)] == []
    assert all(zoo_trained[key] is registry.entry(key).algorithm_class for key in zoo_trained)


def test_an_unknown_key_is_named_with_the_close_ones():
    with pytest.raises(ValueError, match=r"algo 'drqv2ef' \(did you mean 'drqv2_ef'.*\) is not a known algorithm"):
        registry.entry("drqv2ef")
