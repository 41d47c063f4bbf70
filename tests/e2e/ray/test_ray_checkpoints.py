"""A checkpointing sweep on a real two-node Ray cluster on 127.0.0.1 (docs/CHECKPOINTS.md,
"Sweeps"): the Ray workers running its runs killed with SIGKILL once a run checkpointed,
Ray retries their tasks and each retried run goes on from its checkpoint under the
sweep's folder (a path every node writes: here one machine), to the tables of the local
executor's uninterrupted sweep, byte for byte."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from pathlib import Path

import pytest

from bench.local_ray import LocalRayCluster
from flocklab.service.checkpoints import CHECKPOINT
from tests.e2e.ray.test_ray_cli import flocklab_sweep, sweep_cmd, wait_for_task, write
from tests.service.sweeps.test_sweep_checkpoints import EVERY, LONG, TABLES

pytestmark = pytest.mark.ray


def test_killed_ray_workers_retried_tasks_go_on_from_the_runs_checkpoints(
        ray_cluster: LocalRayCluster, tmp_path: Path):
    spec, out = write(tmp_path, {**LONG, "name": "ray-ckpt"}), tmp_path / "out"
    proc = subprocess.Popen(sweep_cmd(spec, out, ray_cluster.address),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    wait_for_task(ray_cluster)
    deadline = time.monotonic() + 120
    while not list(out.glob("runs/*/" + CHECKPOINT)):
        assert time.monotonic() < deadline and proc.poll() is None, "no run checkpointed"
        time.sleep(0.05)
    for pid in ray_cluster.pids("ray::run_chunk"):
        os.kill(pid, signal.SIGKILL)
    got, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err
    line = json.loads(got)
    assert line["status"] == "completed" and line["runs_done"] == 2, line
    resumed = line["checkpoints_resumed"]
    assert resumed and all(0 < s < 3000 and s % EVERY == 0 for s in resumed.values()), line
    for run, step in resumed.items():
        summary = json.loads((out / "runs" / run / "summary.json").read_text())
        assert summary["resumed_from_step"] == step
    local = tmp_path / "local"
    assert flocklab_sweep(spec, local).returncode == 0
    for name in TABLES:
        assert (out / name).read_bytes() == (local / name).read_bytes(), name
    assert not list(out.glob("runs/*/" + CHECKPOINT))
