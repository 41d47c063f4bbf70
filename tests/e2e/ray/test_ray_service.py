"""`flocklab serve` with FLOCKLAB_EXECUTOR=ray on a real two-node Ray cluster on 127.0.0.1:
jobs and sweeps run as Ray tasks while the API process never loads Taichi, the store
stays the source of truth (cancel, kill -9 of the service, an unreachable cluster)."""

from __future__ import annotations

import json
import socket
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from bench.local_ray import LocalRayCluster
from flocklab.service.serve import ServerProcess
from tests.service.conftest import TEST_ENV, _cleanup
from tests.service.svc_helpers import scenario, wait_for

pytestmark = pytest.mark.ray

TERMINAL = ("succeeded", "failed", "cancelled", "timed_out")


def ray_env(address: str) -> dict[str, str]:
    return {**TEST_ENV, "FLOCKLAB_EXECUTOR": "ray", "FLOCKLAB_RAY_ADDRESS": address,
            "FLOCKLAB_CANCEL_GRACE_SECONDS": "4", "FLOCKLAB_MAX_SWEEP_RUNS": "64"}


def sweep_spec(steps: int = 100, n: int = 50, etas: tuple[float, ...] = (0.5, 3.0),
               replicas: int = 2) -> dict[str, Any]:
    return {
        "name": "ray-service",
        "base": {"model": {"kind": "vicsek", "v0": 0.03},
                 "space": {"kind": "periodic", "L": (n / 4) ** 0.5},
                 "neighbours": {"radius": 1.0}, "initial": {"kind": "random", "N": n},
                 "time": {"steps": steps}, "recording": {"every": 0, "observables_every": 10},
                 "seed": 9},
        "axes": [{"path": "model.eta", "values": list(etas)}],
        "replicas": replicas,
        "measure": {"va": {"observable": "polarization", "reduce": "mean", "from_step": 20}},
    }


def submit_sweep(http: httpx.Client, spec: dict[str, Any]) -> str:
    r = http.post("/v1/sweeps", json=spec)
    assert r.status_code == 202, r.text
    return r.json()["id"]


def wait_sweep(http: httpx.Client, sweep_id: str, until: Any = None, timeout: float = 150
               ) -> dict[str, Any]:
    deadline = time.monotonic() + timeout
    while True:
        params = {"wait": 2, "until": "change"} if until else {"wait": 2}
        s = http.get(f"/v1/sweeps/{sweep_id}", params=params).json()
        if until(s) if until else s["status"] in TERMINAL:
            return s
        assert time.monotonic() < deadline, f"sweep still {s['status']} after {timeout} s"


def loads_taichi(pid: int) -> bool:
    """Whether process `pid` has Taichi's native library mapped (it imported Taichi)."""
    return "taichi" in Path(f"/proc/{pid}/maps").read_text()


def wait_for_task(cluster: LocalRayCluster, timeout: float = 90) -> None:
    deadline = time.monotonic() + timeout
    while not cluster.pids("ray::run_chunk"):
        assert time.monotonic() < deadline, "no Ray task started"
        time.sleep(0.1)


def no_task_left(cluster: LocalRayCluster, timeout: float = 20) -> bool:
    deadline = time.monotonic() + timeout
    while cluster.pids("ray::run_") and time.monotonic() < deadline:
        time.sleep(0.2)
    return not cluster.pids("ray::run_")


@pytest.fixture(scope="module")
def ray_server(ray_cluster: LocalRayCluster, tmp_path_factory: pytest.TempPathFactory
               ) -> Iterator[ServerProcess]:
    s = ServerProcess(tmp_path_factory.mktemp("ray-svc") / "data",
                      env=ray_env(ray_cluster.address)).start()
    try:
        yield s
    finally:
        _cleanup(s)


@pytest.fixture
def http(ray_server: ServerProcess) -> Iterator[httpx.Client]:
    with httpx.Client(base_url=ray_server.url, timeout=30) as c:
        yield c


def test_jobs_and_sweeps_run_on_the_cluster_with_the_local_bits(
        ray_server: ServerProcess, http: httpx.Client, tmp_path: Path):
    from flocklab.schemas.sweep import Sweep
    from flocklab.service.sweeps.runner import run_sweep

    spec = sweep_spec()
    sweep_id = submit_sweep(http, spec)
    r = http.post("/v1/jobs", json=scenario(n=60, steps=40, every=10))
    assert r.status_code == 202
    job = wait_for(http, r.json()["id"], timeout=150)
    assert job["status"] == "succeeded", job
    traj = http.get(f"/v1/jobs/{job['id']}/trajectory", params={"format": "json"})
    assert traj.status_code == 200 and len(traj.json()["step"]) == 5
    done = wait_sweep(http, sweep_id)
    assert done["status"] == "succeeded" and done["runs_done"] == 4, done

    local = tmp_path / "local"
    run_sweep(Sweep.model_validate_json(json.dumps(spec)), local)
    for name in ("table", "runs"):
        got = http.get(f"/v1/sweeps/{sweep_id}/{name}", params={"format": "csv"})
        assert got.content == (local / f"{name}.csv").read_bytes(), name
    # Taichi ran on the Ray workers only: neither the API process nor its workers (the
    # Ray drivers) loaded it.
    assert ray_server.proc is not None and not loads_taichi(ray_server.proc.pid)
    assert ray_server.children() and not any(loads_taichi(p) for p in ray_server.children())


def test_cancel_a_running_sweep_cancels_its_tasks(ray_cluster: LocalRayCluster,
                                                  http: httpx.Client):
    sweep_id = submit_sweep(http, sweep_spec(steps=6000, n=100, etas=(0.5, 1.0, 2.0, 3.0)))
    wait_for_task(ray_cluster)
    r = http.post(f"/v1/sweeps/{sweep_id}/cancel")
    assert r.status_code == 202
    done = wait_sweep(http, sweep_id, timeout=60)
    assert done["status"] == "cancelled", done
    assert no_task_left(ray_cluster)


def test_service_killed_and_restarted_loses_nothing_counts_nothing_twice(
        ray_cluster: LocalRayCluster, tmp_path: Path):
    data = tmp_path / "data"
    env = ray_env(ray_cluster.address)
    s1 = ServerProcess(data, env=env).start()
    try:
        with httpx.Client(base_url=s1.url, timeout=30) as http:
            sweep_id = submit_sweep(http, sweep_spec(steps=3000, n=100,
                                                     etas=(0.5, 1.0, 2.0, 3.0)))
            wait_for_task(ray_cluster)
        s1.kill()  # kill -9 the API while tasks run on the cluster
    finally:
        _cleanup(s1)
    s2 = ServerProcess(data, env=env).start()
    try:
        with httpx.Client(base_url=s2.url, timeout=30) as http:
            done = wait_sweep(http, sweep_id, timeout=240)
            assert done["status"] == "succeeded" and done["runs_done"] == 8, done
            runs = http.get(f"/v1/sweeps/{sweep_id}/runs", params={"format": "json"}).json()
            assert sorted(row[0] for row in runs["data"]) == list(range(8))
            listed = http.get("/v1/sweeps").json()["items"]
            assert [s["status"] for s in listed] == ["succeeded"]  # none stuck running
    finally:
        _cleanup(s2)


def test_an_unreachable_cluster_fails_jobs_with_a_problem_naming_it(tmp_path: Path):
    with socket.socket() as sock:  # a port nobody listens on
        sock.bind(("127.0.0.1", 0))
        address = f"127.0.0.1:{sock.getsockname()[1]}"
    s = ServerProcess(tmp_path / "data", env=ray_env(address)).start()
    try:
        with httpx.Client(base_url=s.url, timeout=30) as http:
            sweep = wait_sweep(http, submit_sweep(http, sweep_spec()), timeout=60)
            r = http.post("/v1/jobs", json=scenario())
            job = wait_for(http, r.json()["id"], timeout=60)
            for ended in (sweep, job):
                assert ended["status"] == "failed", ended
                err = ended["error"]
                assert err["type"].endswith("cluster-unavailable") and err["status"] == 503
                assert address in err["detail"] and err["ray_address"] == address
            assert http.get("/healthz").status_code == 200
    finally:
        _cleanup(s)
