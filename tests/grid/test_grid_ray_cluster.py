"""The tiny grid through `sb3-ef benchmark --backend ray --address ...` on a real two-node Ray cluster.

A head (`ray start --head`) and a second node (`ray start --address`), one CPU each, run in a network namespace of
their own that holds only the loopback interface, so that the cluster lives on 127.0.0.1 (Ray resolves a loopback
``--node-ip-address`` to the machine's outward address otherwise). This file is also the script run inside that
namespace: it starts both nodes, runs the grid, and stops the nodes' process groups.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

from sb3_ef.grid import load_grid
from sb3_ef.grid.run import RunPaths

TINY_GRID = Path(__file__).parent / "tiny_grid.yml"
PORT = 6380
STARTUP_TIMEOUT_S = 180


def _start_node(*arguments: str) -> subprocess.Popen:
    """`ray start --block` in its own process group, so that stopping it stops exactly this node's processes."""
    command = [shutil.which("ray") or "ray", "start", "--block", "--num-cpus=1", "--disable-usage-stats"]
    return subprocess.Popen([*command, *arguments], start_new_session=True, stdout=subprocess.DEVNULL)


def _stop(node: subprocess.Popen) -> None:
    try:
        os.killpg(node.pid, signal.SIGTERM)
        node.wait(timeout=10)  # a node drains for up to 30 s on SIGTERM: the grid has finished, so cut it short
    except subprocess.TimeoutExpired:
        os.killpg(node.pid, signal.SIGKILL)
        node.wait()
    except ProcessLookupError:
        pass


def _wait_for_nodes(address: str, count: int, deadline: float) -> None:
    import ray

    while True:
        try:
            ray.init(address=address, log_to_driver=False)
            break
        except (ConnectionError, RuntimeError):  # the head's GCS is not up yet
            assert time.monotonic() < deadline, f"the Ray head at {address} did not start"
            time.sleep(1)
    try:
        while sum(node["Alive"] for node in ray.nodes()) < count:
            assert time.monotonic() < deadline, f"{count} Ray nodes did not join"
            time.sleep(1)
    finally:
        ray.shutdown()


def run_grid_on_two_nodes(out: str) -> int:
    """Inside the namespace: loopback up, head and second node, the grid through the CLI, nodes stopped."""
    from sb3_ef.cli import main as sb3_ef_main

    subprocess.run(["ip", "link", "set", "lo", "up"], check=True)
    address = f"127.0.0.1:{PORT}"
    deadline = time.monotonic() + STARTUP_TIMEOUT_S
    nodes = [_start_node("--head", f"--port={PORT}", "--node-ip-address=127.0.0.1", "--include-dashboard=false")]
    try:
        _wait_for_nodes(address, 1, deadline)
        nodes.append(_start_node(f"--address={address}", "--node-ip-address=127.0.0.1"))
        _wait_for_nodes(address, 2, deadline)
        return sb3_ef_main(["benchmark", str(TINY_GRID), "--out", out, "--backend", "ray", "--address", address])
    finally:
        for node in reversed(nodes):
            _stop(node)


def _can_make_network_namespaces() -> bool:
    probe = subprocess.run(["unshare", "-n", "true"], capture_output=True) if shutil.which("unshare") else None
    return probe is not None and probe.returncode == 0 and shutil.which("ip") is not None


@pytest.mark.slow
def test_the_grid_runs_on_both_nodes_of_a_two_node_cluster(tmp_path):
    pytest.importorskip("ray")
    if not _can_make_network_namespaces():
        pytest.skip("needs `unshare -n` (root or user namespaces) and `ip` for a loopback-only network namespace")
    out = tmp_path / "out"
    # A short temporary folder: Ray's socket paths must stay under 108 characters.
    ray_temp = tempfile.mkdtemp(prefix="ray", dir="/tmp")
    environment = {**os.environ, "RAY_AUTH_MODE": "disabled", "RAY_TMPDIR": ray_temp}
    environment["PYTHONPATH"] = os.pathsep.join(filter(None, [str(Path.cwd()), environment.get("PYTHONPATH")]))
    try:
        finished = subprocess.run(
            ["unshare", "-n", sys.executable, __file__, str(out)], env=environment, capture_output=True, text=True
        )
    finally:
        shutil.rmtree(ray_temp, ignore_errors=True)
    assert finished.returncode == 0, finished.stdout[-3000:] + finished.stderr[-3000:]

    results = [json.loads(RunPaths.of(out, spec).result.read_text()) for spec in load_grid(TINY_GRID)]
    assert [result["status"] for result in results] == ["done"] * 4
    assert all(result["steps"] == 200 and len(result["records"]) == 2 for result in results)
    # One CPU per node and one CPU per run: the four runs are spread over both nodes.
    assert len({result["node"] for result in results}) == 2


if __name__ == "__main__":
    raise SystemExit(run_grid_on_two_nodes(sys.argv[1]))
