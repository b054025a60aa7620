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
