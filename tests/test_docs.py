"""The user-facing docs and configs stand alone: they cite no file that is not in the repository."""

from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCUMENTS = sorted(
    [ROOT / "README.md", *ROOT.glob("docs/*.md"), *ROOT.glob("zoo_configs/*.yml"), *ROOT.glob("benchmarks/*.md")]
)


@pytest.mark.parametrize("path", DOCUMENTS, ids=lambda path: str(path.relative_to(ROOT)))
def test_no_citation_of_files_outside_the_repository(path):
    text = path.read_text()
    for name in ("REFERENCE.md", "PLATFORM-NOTES.md"):
        assert name not in text, f"{path.relative_to(ROOT)} cites {name}, which is not in the repository"
