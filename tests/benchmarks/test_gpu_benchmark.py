"""benchmarks/gpu.py runs its code paths on a CPU (``--smoke``) and writes its JSON and Markdown table."""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "gpu.py"


def load_script():
    spec = importlib.util.spec_from_file_location("gpu_benchmark", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def test_smoke_run_of_one_algorithm_writes_its_results(tmp_path):
    gpu = load_script()
    out = tmp_path / "gpu"
    gpu.main(["--device", "cpu", "--smoke", "--algorithms", "DrQv2", "--modes", "eager", "--out", str(out)])
    results = json.loads(out.with_suffix(".json").read_text())["results"]
    assert [(r["algorithm"], r["compiled"], r["status"]) for r in results] == [("DrQv2", False, "ok")]
    row = results[0]
    assert row["storage_device"] == "cpu" and row["buffer_gb"] > 0
    assert all(row[field] > 0 for field in ("sample_ms", "updates_per_s", "env_steps_per_s"))
    table = out.with_suffix(".md").read_text()
    assert "SMOKE RUN" in table and "| DrQv2 | 84x84 | eager | ok | cpu |" in table


def test_precision_bf16_runs_the_algorithms_in_bf16(tmp_path):
    gpu = load_script()
    out = tmp_path / "gpu"
    argv = ["--device", "cpu", "--smoke", "--algorithms", "TDMPC2EF", "--modes", "eager", "--precision", "bf16"]
    gpu.main([*argv, "--out", str(out)])
    written = json.loads(out.with_suffix(".json").read_text())
    assert "precision bf16" in written["header"] and [r["status"] for r in written["results"]] == ["ok"]
    model = gpu.build("TDMPC2EF", False, gpu.th.device("cpu"), gpu.SMOKE, True, "bf16")
    assert model.precision == "bf16"
    model.env.close()


def test_a_run_past_the_budget_is_recorded_as_skipped(tmp_path):
    gpu = load_script()
    out = tmp_path / "gpu"
    gpu.main(["--device", "cpu", "--smoke", "--budget-s", "-1", "--algorithms", "TDMPC2EF", "--out", str(out)])
    results = json.loads(out.with_suffix(".json").read_text())["results"]
    assert [r["status"] for r in results] == ["skipped (time budget)"] * 2


@pytest.mark.slow
def test_whole_smoke_run(tmp_path):
    """Every algorithm, eager and compiled (CURL and Dreamer-v3 eager only)."""
    out = tmp_path / "gpu"
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    command = [sys.executable, str(SCRIPT), "--device", "cpu", "--smoke", "--out", str(out)]
    subprocess.run(command, check=True, env=env, timeout=600)
    results = json.loads(out.with_suffix(".json").read_text())["results"]
    assert len(results) == 14
    assert sum(r["compiled"] for r in results) == 7
    skipped = [(r["algorithm"], r["compiled"]) for r in results if r["status"] != "ok"]
    assert skipped == [("CURL", True), ("DreamerV3", True)]  # their updates have no compiled mode
    assert results[-1]["status"] == "skipped (no compiled mode)"
