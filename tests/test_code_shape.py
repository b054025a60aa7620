"""The package stays small enough to read: short files, short functions, and a ceiling on its total size."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "sb3_ef"
#: Lines in one module of the package, at most.
MAX_FILE_LINES = 500
#: Lines in one function or method (its ``def`` line to its last line, decorators not counted), at most.
MAX_FUNCTION_LINES = 80
#: Lines of Python in the whole package (``find sb3_ef -name '*.py' | xargs cat | wc -l``), at most.
MAX_PACKAGE_LINES = 19_150


def _modules() -> dict[str, str]:
    sources = {str(path.relative_to(PACKAGE.parent)): path.read_text() for path in sorted(PACKAGE.rglob("*.py"))}
    assert sources, f"no Python files under {PACKAGE}"
    return sources


def _lines(source: str) -> int:
    return source.count("\n")


def test_no_module_is_over_the_file_limit():
    long = {name: _lines(source) for name, source in _modules().items() if _lines(source) > MAX_FILE_LINES}
    assert not long, f"modules over {MAX_FILE_LINES} lines: {long}"


def test_no_function_is_over_the_function_limit():
    long = {}
    for name, source in _modules().items():
        for node in ast.walk(ast.parse(source, filename=name)):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                length = node.end_lineno - node.lineno + 1
                if length > MAX_FUNCTION_LINES:
                    long[f"{name}:{node.lineno} {node.name}"] = length
    assert not long, f"functions over {MAX_FUNCTION_LINES} lines: {long}"


def test_the_package_is_within_its_line_budget():
    total = sum(_lines(source) for source in _modules().values())
    assert total <= MAX_PACKAGE_LINES, f"sb3_ef/ has {total} lines of Python, over the budget of {MAX_PACKAGE_LINES}"
