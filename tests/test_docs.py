"""The user-facing docs and configs stand alone: they cite no file that is not in the repository, and every file,
module and package name they cite is there (code that moves takes its citations with it)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

import sb3_ef

ROOT = Path(__file__).resolve().parents[1]
DOCUMENTS = sorted(
    [ROOT / "README.md", *ROOT.glob("docs/*.md"), *ROOT.glob("zoo_configs/*.yml"), *ROOT.glob("benchmarks/*.md")]
)


@pytest.mark.parametrize("path", DOCUMENTS, ids=lambda path: str(path.relative_to(ROOT)))
def test_no_citation_of_files_outside_the_repository(path):
    text = path.read_text()
    for name in ("REFERENCE.md", "PLATFORM-NOTES.md"):
        assert name not in text, f"{path.relative_to(ROOT)} cites {name}, which is not in the repository"


#: A repository path: a file with a suffix, or a folder written with a trailing slash (a command's output paths,
#: written without either, are not checked).
REPOSITORY_PATH = re.compile(
    r"(?<![\w/.-])((?:benchmarks|docs|experiments|notebooks|sb3_ef|tests|zoo_configs)/[\w./-]*(?:\.[a-z]+|/))(?![\w*])"
)
#: A dotted name in the package: modules, then at most one attribute of the last module.
PACKAGE_NAME = re.compile(r"(?<![\w.])(sb3_ef(?:\.\w+)+)")
NOTEBOOKS = sorted(ROOT.glob("notebooks/*.ipynb"))


@pytest.mark.parametrize("path", DOCUMENTS, ids=lambda path: str(path.relative_to(ROOT)))
def test_cited_repository_files_exist(path):
    missing = sorted({cited for cited in REPOSITORY_PATH.findall(path.read_text()) if not (ROOT / cited).exists()})
    assert not missing, f"{path.relative_to(ROOT)} cites files that are not in the repository: {missing}"


def _module_source(parts: list[str]) -> str | None:
    base = ROOT.joinpath(*parts)
    for candidate in (base.with_suffix(".py"), base / "__init__.py"):
        if candidate.is_file():
            return candidate.read_text()
    return None


def _resolves(dotted: str) -> bool:
    """The longest prefix of ``dotted`` that is a module of the package exists, and the next name, if any, is defined
    or imported in that module's source (or exported by the root)."""
    parts = dotted.split(".")
    for end in range(len(parts), 0, -1):
        source = _module_source(parts[:end])
        if source is not None:
            rest = parts[end:]
            exported = end == 1 and rest[0] in sb3_ef.__all__  # the root's names derive from the registry
            return not rest or exported or re.search(rf"\b{rest[0]}\b", source) is not None
    return False


@pytest.mark.parametrize("path", DOCUMENTS + NOTEBOOKS, ids=lambda path: str(path.relative_to(ROOT)))
def test_cited_package_names_exist(path):
    missing = sorted({name for name in PACKAGE_NAME.findall(path.read_text()) if not _resolves(name)})
    assert not missing, f"{path.relative_to(ROOT)} cites names that are not in sb3_ef: {missing}"


def test_readme_cpu_try_is_the_timed_one_and_shows_progress():
    """The README's CPU try is what benchmarks/cpu_try.py times (so its stated time holds), with a progress bar."""
    import importlib.util
    import re

    readme = (ROOT / "README.md").read_text()
    code = re.search(r"A CPU try:.*?```python\n(.*?)```", readme, re.DOTALL).group(1)
    calls = {}

    class Recorder:
        def __init__(self, policy, env, **kwargs):
            calls["kwargs"] = kwargs

        def learn(self, total_timesteps, **kwargs):
            calls["learn"] = (total_timesteps, kwargs)

    exec(code, {"make_env": lambda *args, **kwargs: calls.setdefault("env", (args, kwargs)), "DrQv2EF": Recorder})
    spec = importlib.util.spec_from_file_location("cpu_try", ROOT / "benchmarks" / "cpu_try.py")
    timed = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(timed)
    assert calls["kwargs"] == timed.KWARGS
    assert calls["learn"] == (timed.STEPS, {"progress_bar": True})
    assert calls["env"] == (("dmc/cartpole-swingup",), {"size": 64, "fast_render": True})
    assert "CPU_TRY_TIME" not in readme and "min" in readme[readme.index("A CPU try:") :][:300]
