"""The cluster lost mid-sweep (run last: it ends the session's cluster)."""

from __future__ import annotations

import subprocess
import time
from pathlib import Path

import pytest

from bench.local_ray import LocalRayCluster
from tests.e2e.ray.test_ray_cli import (
    read_journal_count,
    sweep_cmd,
    sweep_doc,
    wait_for_task,
    write,
)

pytestmark = pytest.mark.ray


def test_the_cluster_lost_mid_sweep_is_an_error_naming_it(ray_cluster: LocalRayCluster,
                                                          tmp_path: Path):
    doc = sweep_doc(steps=6000, n=100, etas=(0.5, 1.0, 2.0, 3.0), replicas=2)
    spec, out = write(tmp_path, doc), tmp_path / "out"
    proc = subprocess.Popen(sweep_cmd(spec, out, ray_cluster.address),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    wait_for_task(ray_cluster)
    ray_cluster.stop()
    t0 = time.monotonic()
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 3, err
    assert ray_cluster.address in err and "Traceback" not in err
    assert time.monotonic() - t0 < 90
    assert read_journal_count(out) < 8  # what finished before is kept for a resume
