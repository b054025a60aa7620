"""benchmarks/precision.py times float32, bf16 and the authors' updates and planner side by side, and writes its
JSON and Markdown tables."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "precision.py"


def test_one_round_of_updates_and_plans_writes_every_variant(tmp_path):
    spec = importlib.util.spec_from_file_location("precision_benchmark", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    out = tmp_path / "precision"
    argv = ["--sections", "updates", "plan", "--updates", "DrQv2-EF", "TD-MPC2", "--threads", "1"]
    module.main([*argv, "--batch-sizes", "4", "--repeats", "1", "--out", str(out)])
    results = json.loads(out.with_suffix(".json").read_text())["results"]
    assert [row["update"] for row in results["updates"]] == ["DrQv2-EF", "TD-MPC2"]
    for row in [*results["updates"], *results["plan"]]:
        assert all(row[f"{variant}_ms"] > 0 for variant in ("authors", "fp32", "bf16"))
    assert results["plan"][0]["gflop_per_action"] > 1  # 6 iterations of 512 samples through the world model
    table = out.with_suffix(".md").read_text()
    assert "| DrQv2-EF | 1 | 4 |" in table and "| TD-MPC2 plan, threads |" in table
