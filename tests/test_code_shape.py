"""The package stays readable: short modules and short functions, counted in code lines (docstrings, comments and
blank lines are free, so that the seams keep their words)."""

from __future__ import annotations

import ast
import io
import tokenize
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "sb3_ef"
#: Code lines in one module of the package, at most.
MAX_FILE_LINES = 400
#: Code lines in one function or method (a host's ``_update`` reads top to bottom in one place), at most.
MAX_FUNCTION_LINES = 100
_NOT_CODE = {tokenize.COMMENT, tokenize.NL, tokenize.NEWLINE, tokenize.INDENT, tokenize.DEDENT, tokenize.ENDMARKER}


def code_lines(source: str) -> set[int]:
    """The numbers of the lines of ``source`` that hold code: not blank, not only a comment, not in a docstring."""
    lines = {
        number
        for token in tokenize.generate_tokens(io.StringIO(source).readline)
        if token.type not in _NOT_CODE
        for number in range(token.start[0], token.end[0] + 1)
    }
    for node in ast.walk(ast.parse(source)):
        documented = isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef)
        if documented and ast.get_docstring(node, clean=False) is not None:
            lines -= set(range(node.body[0].lineno, node.body[0].end_lineno + 1))
    return lines


def _modules() -> dict[str, str]:
    sources = {str(path.relative_to(PACKAGE.parent)): path.read_text() for path in sorted(PACKAGE.rglob("*.py"))}
    assert sources, f"no Python files under {PACKAGE}"
    return sources


def test_code_lines_leave_out_docstrings_comments_and_blank_lines():
    source = 'def f(x):\n    """Doc.\n\n    More."""\n\n    # a comment\n    return (x +\n            1)  # why\n'
    assert code_lines(source) == {1, 7, 8}


def test_no_module_is_over_the_file_limit():
    long = {name: len(code_lines(source)) for name, source in _modules().items()}
    assert {name: count for name, count in long.items() if count > MAX_FILE_LINES} == {}


def test_no_function_is_over_the_function_limit():
    long = {}
    for name, source in _modules().items():
        lines = code_lines(source)
        for node in ast.walk(ast.parse(source, filename=name)):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                length = len(lines & set(range(node.lineno, node.end_lineno + 1)))
                if length > MAX_FUNCTION_LINES:
                    long[f"{name}:{node.lineno} {node.name}"] = length
    assert long == {}, f"functions over {MAX_FUNCTION_LINES} code lines: {long}"
