"""``sb3_ef.offline``'s public names, imported lazily (tests/test_import_layers.py: the import rules)."""

from __future__ import annotations

import subprocess
import sys

from sb3_ef.offline import pretrain as pretrain_function


def test_the_public_names_are_the_functions_and_classes_even_after_their_modules_are_imported():
    import sb3_ef.offline.collect
    import sb3_ef.offline.evaluate  # the module of the same name as the function
    from sb3_ef.offline import LeRobotDataset, collect, evaluate, open_dataset, pretrain
    from sb3_ef.offline.collect import collect as collect_function
    from sb3_ef.offline.lerobot import LeRobotDataset as reader

    assert collect is collect_function and pretrain is pretrain_function and callable(evaluate)
    assert LeRobotDataset is reader and open_dataset.__module__ == "sb3_ef.offline.readers"
    for name in set(sb3_ef.offline.__all__) - {"OXE_LAYOUTS"}:
        assert getattr(sb3_ef.offline, name).__name__ == name, name
    assert "droid" in sb3_ef.offline.OXE_LAYOUTS


def test_importing_the_package_does_not_import_torch():
    code = "import sys, sb3_ef.offline; print('torch' in sys.modules)"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "False"
