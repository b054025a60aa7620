"""The two layers: the library (what ``DrQv2EF("CnnPolicy", env).learn(n)`` needs) loads nothing of the workbench
above it nor of the workbench's dependencies, and no module of the package imports itself through others.

pyproject.toml's import-linter contracts (``lint-imports``) hold the first for every import statement; the test
here holds it for what a user's program really loads, lazy imports included."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import grimp

import sb3_ef

#: The workbench packages and modules (docs/architecture.md).
WORKBENCH = ("zoo", "grid", "analysis", "offline", "dreamerv3", "cli", "upgrade")
#: What only the workbench may bring in.
WORKBENCH_DEPENDENCIES = ("rl_zoo3", "optuna", "ray", "sheeprl", "hydra", "lightning", "minari", "h5py")

#: Each library class built on the toy pixel env and stepped past its first update, then the loaded modules printed.
_BUILD_EACH = """
import json, sys
from sb3_ef import CURL, SACEF, SEAR, TDMPC2EF, DrQv2EF
from sb3_ef.envs.toy import ToyAgentEnv
from tests.helpers.drqv2 import TINY_POLICY
from tests.helpers.tdmpc2 import TINY_EF_POLICY

small = dict(buffer_size=100, learning_starts=4, batch_size=2, device="cpu", seed=0)
ef = dict(ef_horizon=2, babbling_steps=0)
models = [
    DrQv2EF("CnnPolicy", ToyAgentEnv(size=32), policy_kwargs=TINY_POLICY, **small, **ef),
    SEAR("CnnPolicy", ToyAgentEnv(size=32, agent_masks=True), policy_kwargs={"features_dim": 32}, **small),
    TDMPC2EF("CnnPolicy", ToyAgentEnv(size=64), policy_kwargs=TINY_EF_POLICY, **small, **ef),
    CURL("CnnPolicy", ToyAgentEnv(size=92), **small),
    SACEF("CnnPolicy", ToyAgentEnv(size=64), agent_dim=8, **small, **ef),
]
for model in models:
    model.learn(5)
print(json.dumps(sorted(sys.modules)))
"""


def test_the_library_classes_load_no_workbench_module_and_none_of_its_dependencies():
    repo = Path(__file__).parents[1]
    result = subprocess.run(
        [sys.executable, "-c", _BUILD_EACH], capture_output=True, text=True, cwd=repo, env={"MUJOCO_GL": "egl"}
    )
    assert result.returncode == 0, result.stderr[-3000:]
    loaded = json.loads(result.stdout.strip().splitlines()[-1])
    workbench = [name for name in loaded if name.split(".")[:2] in (["sb3_ef", part] for part in WORKBENCH)]
    dependencies = [name for name in loaded if name.split(".")[0] in WORKBENCH_DEPENDENCIES]
    assert "sb3_ef.drqv2.drqv2" in loaded and "sb3_ef.curl.curl" in loaded  # the classes were built
    assert workbench == [] and dependencies == []


def test_no_import_circle_at_all():
    """No module imports itself through others (``a -> b -> a``, ``a -> b -> c -> a``): the import graph is acyclic.
    Every import statement counts: at module level, inside functions and under ``if TYPE_CHECKING:``."""
    graph = grimp.build_graph(sb3_ef.__name__, cache_dir=None)
    assert "sb3_ef.grid.run" in graph.find_modules_directly_imported_by("sb3_ef.dreamerv3.grid_run")  # graph read
    circles = sorted(
        " -> ".join([module, *graph.find_shortest_chain(imported, module)])
        for module in graph.modules
        for imported in graph.find_modules_directly_imported_by(module)
        if graph.chain_exists(imported, module)
    )
    assert circles == []
