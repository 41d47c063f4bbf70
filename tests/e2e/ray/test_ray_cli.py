"""`flocklab sweep --executor ray` on a real two-node Ray cluster on 127.0.0.1: the same
table and trajectories as the local executor, Ctrl-C, a Ray worker killed mid-task, the
second node killed, and a cluster that is not there."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import pytest

from bench.local_ray import LocalRayCluster

pytestmark = pytest.mark.ray


def sweep_doc(steps: int = 200, n: int = 50, etas: tuple[float, ...] = (0.5, 2.0, 4.0),
              replicas: int = 2, keep: str = "summaries", every: int = 0) -> dict[str, Any]:
    return {
        "name": "ray-cli",
        "base": {
            "model": {"kind": "vicsek", "v0": 0.03},
            "space": {"kind": "periodic", "L": (n / 4) ** 0.5},
            "neighbours": {"radius": 1.0},
            "initial": {"kind": "random", "N": n},
            "time": {"steps": steps},
            "recording": {"every": every, "observables_every": 10,
                          "arrays": ["position", "heading"]},
            "seed": 5,
        },
        "axes": [{"path": "model.eta", "values": list(etas)}],
        "replicas": replicas,
        "measure": {"va": {"observable": "polarization", "reduce": "mean", "from_step": 50}},
        "series": ["polarization"],
        "keep": keep,
    }


def write(tmp: Path, doc: dict[str, Any]) -> Path:
    path = tmp / f"{doc['name']}-{len(list(tmp.iterdir()))}.json"
    path.write_text(json.dumps(doc))
    return path


def sweep_cmd(spec: Path, out: Path, address: str | None) -> list[str]:
    cmd = [sys.executable, "-m", "flocklab", "sweep", str(spec), "--out", str(out)]
    return cmd + (["--executor", "ray", "--ray-address", address] if address else [])


def flocklab_sweep(spec: Path, out: Path, address: str | None = None,
                   timeout: float = 240) -> subprocess.CompletedProcess[str]:
    return subprocess.run(sweep_cmd(spec, out, address), capture_output=True, text=True,
                          timeout=timeout)


def run_indices(out: Path) -> list[int]:
    """The run column of runs.csv, in order."""
    lines = (out / "runs.csv").read_text().splitlines()[1:]
    return [int(line.split(",")[0]) for line in lines]


def read_journal_count(out: Path) -> int:
    """Runs recorded in the sweep's journal."""
    path = out / "runs.jsonl"
    return len(path.read_text().splitlines()) if path.exists() else 0


def wait_for_task(cluster: LocalRayCluster, timeout: float = 90) -> list[int]:
    """Pids of Ray workers running one of our chunks (Ray titles them ray::run_chunk)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        pids = cluster.pids("ray::run_chunk")
        if pids:
            return pids
        time.sleep(0.1)
    raise AssertionError("no Ray task started")


def test_same_bits_as_local_table_series_and_trajectories(ray_cluster: LocalRayCluster,
                                                          tmp_path: Path):
    spec = write(tmp_path, sweep_doc(keep="all", every=50, etas=(0.5, 4.0)))
    local, ray = tmp_path / "local", tmp_path / "ray"
    assert flocklab_sweep(spec, local).returncode == 0
    res = flocklab_sweep(spec, ray, ray_cluster.address)
    assert res.returncode == 0, res.stderr
    assert json.loads(res.stdout)["runs_done"] == 4
    for name in ("table.csv", "series.csv", "runs.csv", "sweep.json"):
        assert (ray / name).read_bytes() == (local / name).read_bytes(), name
    for i in range(4):  # the trajectories written by Ray workers equal the local ones
        with h5py.File(local / "runs" / str(i) / "trajectory.h5") as a, \
                h5py.File(ray / "runs" / str(i) / "trajectory.h5") as b:
            for arr in ("position", "heading"):
                key = f"particles/swarm/{arr}/value"
                assert np.array_equal(a[key][()], b[key][()]), (i, arr)
                assert len(a[key]) >= 4


def test_ctrl_c_cancels_the_outstanding_tasks_and_resume_finishes(
        ray_cluster: LocalRayCluster, tmp_path: Path):
    doc = sweep_doc(steps=2500, n=100, etas=(0.5, 1.0, 2.0, 3.0), replicas=2)
    spec, out = write(tmp_path, doc), tmp_path / "out"
    proc = subprocess.Popen(sweep_cmd(spec, out, ray_cluster.address),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    wait_for_task(ray_cluster)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 1 and "interrupted" in err, err
    deadline = time.monotonic() + 20  # the cancelled tasks end: no worker runs a chunk
    while ray_cluster.pids("ray::run_chunk") and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not ray_cluster.pids("ray::run_chunk")
    res = flocklab_sweep(spec, out, ray_cluster.address)
    assert res.returncode == 0, res.stderr
    assert json.loads(res.stdout)["status"] == "completed"
    assert run_indices(out) == list(range(8))


def test_a_killed_ray_worker_is_retried_and_no_run_counted_twice(
        ray_cluster: LocalRayCluster, tmp_path: Path):
    doc = sweep_doc(steps=1500, n=400, etas=(0.5, 2.0), replicas=2)
    spec, out = write(tmp_path, doc), tmp_path / "out"
    proc = subprocess.Popen(sweep_cmd(spec, out, ray_cluster.address),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    victim = wait_for_task(ray_cluster)[0]
    os.kill(victim, signal.SIGKILL)
    got, err = proc.communicate(timeout=180)
    assert proc.returncode == 0, err
    assert json.loads(got)["runs_done"] == 4
    assert run_indices(out) == [0, 1, 2, 3]
    local = tmp_path / "local"
    assert flocklab_sweep(spec, local).returncode == 0
    assert (out / "table.csv").read_bytes() == (local / "table.csv").read_bytes()


def test_an_unreachable_cluster_is_a_clear_error_naming_the_address(tmp_path: Path):
    spec = write(tmp_path, sweep_doc())
    with __import__("socket").socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        address = f"127.0.0.1:{s.getsockname()[1]}"
    t0 = time.monotonic()
    res = flocklab_sweep(spec, tmp_path / "out", address, timeout=60)
    assert res.returncode == 3 and time.monotonic() - t0 < 30
    assert f"cannot connect to the Ray cluster at {address}" in res.stderr
    assert "Traceback" not in res.stderr


def test_the_second_node_killed_its_tasks_rerun_on_the_head(ray_cluster: LocalRayCluster,
                                                           tmp_path: Path):
    # Long enough runs that the second node is seen running one: with 2000 steps a
    # full-suite run's sweep finished before the poll saw any there.
    doc = sweep_doc(steps=10_000, n=400, etas=(0.5, 1.0, 2.0, 4.0), replicas=2)
    spec, out = write(tmp_path, doc), tmp_path / "out"
    proc = subprocess.Popen(sweep_cmd(spec, out, ray_cluster.address),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 90
    while not set(ray_cluster.second_node_pids()) & set(ray_cluster.pids("ray::run_chunk")):
        assert time.monotonic() < deadline and proc.poll() is None, \
            "no task was seen on the second node while the sweep ran"
        time.sleep(0.05)
    try:
        for pid in ray_cluster.second_node_pids():
            os.kill(pid, signal.SIGKILL)
        got, err = proc.communicate(timeout=180)
        assert proc.returncode == 0, err
        assert json.loads(got)["runs_done"] == 8
        assert run_indices(out) == list(range(8))
    finally:
        ray_cluster.start_second_node()  # for the tests after this one
