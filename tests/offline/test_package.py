"""``sb3_ef.offline``'s public names, imported lazily, and the import graph of its modules (no circle)."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import sb3_ef.offline
from sb3_ef.offline import pretrain as pretrain_function

PACKAGE = Path(sb3_ef.offline.__file__).parent


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


def _imports(path: Path) -> set[str]:
    """The ``sb3_ef.offline`` modules ``path`` imports, at module level or inside functions."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module:
            modules = [node.module] + [f"{node.module}.{alias.name}" for alias in node.names]
            names |= {module for module in modules if (PACKAGE / f"{module.split('.')[-1]}.py").is_file()}
        elif isinstance(node, ast.Import):
            names |= {alias.name for alias in node.names}
    return {name.split(".")[-1] for name in names if name.startswith("sb3_ef.offline.")}


def test_the_modules_import_each_other_without_a_circle():
    graph = {path.stem: _imports(path) - {path.stem} for path in PACKAGE.glob("*.py") if path.stem != "__init__"}
    visiting, done = set(), set()

    def visit(module: str, trail: list[str]) -> None:
        assert module not in visiting, f"import circle: {' -> '.join([*trail, module])}"
        if module in done:
            return
        visiting.add(module)
        for imported in sorted(graph.get(module, ())):
            visit(imported, [*trail, module])
        visiting.discard(module)
        done.add(module)

    for module in sorted(graph):
        visit(module, [])
    assert "readers" in graph["rlds"] or "dataset" in graph["rlds"]  # the graph was read
