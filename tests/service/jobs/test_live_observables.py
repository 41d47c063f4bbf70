"""Observables while a job runs: the engine's `on_observations` hand-over (both engine
paths, bits unchanged), the live file the run folder holds meanwhile, and
`GET /v1/jobs/{id}/observables` on the real app (rows grow while running; the final
answer is observables.csv), with the Python client's `Job.observables()`."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from flocklab import Client
from flocklab.schemas import PRESETS, Scenario
from flocklab.service.live_observables import LIVE_FILE, LiveObservables, complete_rows
from tests.service.svc_helpers import assert_problem, scenario, submit, wait_for


def _scenario(steps: int, n: int = 100, dimension: int = 2, every: int = 10) -> Scenario:
    spec = scenario(n=n, steps=steps, every=0, backend="cpu", threads=1)
    spec["recording"]["observables_every"] = every
    if dimension == 3:
        spec["space"]["dimension"] = 3
    return Scenario.model_validate(spec)


def _preset(name: str, steps: int) -> Scenario:
    spec = PRESETS[name].build()
    spec["time"]["steps"] = steps
    spec["recording"]["every"] = 0
    spec["threads"] = 1
    return Scenario.model_validate(spec)


@pytest.mark.slow_cases("flocking-fused", "vicsek-fused")
@pytest.mark.parametrize("path, sc", [
    ("fused", _scenario(20_000)),  # 2D, N <= 10^4: the fused small-N kernels
    # the flocking kernels' rows, lambda2 (computed per window on the host) among them
    ("fused", _preset("tjp-switching", 40_000)),
    ("per_step", _scenario(100, dimension=3, every=1)),  # forced onto the per-step path
], ids=["vicsek-fused", "flocking-fused", "vicsek-3d-per-step"])
def test_rows_handed_over_are_a_prefix_and_change_no_bit(path, sc):
    from flocklab import kernels

    alone = kernels.run(sc, path=path)
    got: list[dict[str, np.ndarray]] = []
    # interval 0: rows at every progress point (per step) or window end (fused), so even
    # a short run hands some over
    live = kernels.run(sc, on_observations=got.append, observations_interval=0.0,
                       path=path)
    assert live.extra["engine_path"] == path
    assert list(live.observables) == list(alone.observables)
    for k, v in alone.observables.items():
        assert np.array_equal(live.observables[k], v, equal_nan=True), k
    assert got, "no rows handed over while the run went on"
    assert all(list(g) == list(live.observables) for g in got)  # the final columns
    joined = {k: np.concatenate([g[k] for g in got]) for k in got[0]}
    n = len(joined["step"])
    assert 0 < n <= len(live.observables["step"])
    for k, v in joined.items():
        assert np.array_equal(v, live.observables[k][:n], equal_nan=True), k


def test_live_file_never_shows_half_a_row(tmp_path):
    path = tmp_path / LIVE_FILE
    live = LiveObservables(path)
    assert not path.exists()  # nothing until the first batch
    live.append({"step": np.array([0.0, 10.0]), "time": np.array([0.0, 1.0]),
                 "polarization": np.array([0.1, 1 / 3])})
    live.append({"step": np.array([20.0]), "time": np.array([2.0]),
                 "polarization": np.array([np.nan])})
    with path.open("a") as f:
        f.write("30,3,0.5")  # a batch caught half-written: no newline yet
    names, rows = complete_rows(path)
    assert names == ["step", "time", "polarization"]
    got = list(rows)
    assert [r[0] for r in got] == ["0", "10", "20"]
    assert float(got[1][2]) == 1 / 3  # %.17g reads back to the same float
    assert [r[0] for r in complete_rows(path, start=1, limit=1)[1]] == ["10"]
    live.remove()
    assert not path.exists()


def test_finished_run_folder_holds_no_live_file(tmp_path):
    from flocklab.service.execute import execute_to_dir

    execute_to_dir(_scenario(20_000), tmp_path / "run")
    assert sorted(p.name for p in (tmp_path / "run").iterdir()) == [
        "observables.csv", "scenario.json", "summary.json", "trajectory.h5"]


def _final_csv(server, job_id: str) -> dict[str, np.ndarray]:
    path = Path(server.data_dir) / "results" / job_id / "observables.csv"
    table = np.genfromtxt(path, delimiter=",", names=True)
    return {k: np.atleast_1d(table[k]) for k in table.dtype.names}


@pytest.mark.slow
def test_rows_grow_while_running_and_end_as_observables_csv(server, http):
    # Rows land once per driver window (about 0.1 s of work): the run must last several
    # windows on a quiet machine too (60,000 steps took two), and the poll must be quicker.
    spec = scenario(n=100, steps=200_000, every=0)
    spec["recording"]["observables_every"] = 100
    job = submit(http, spec)
    held: dict[str, list[float | None]] = {}
    seen: list[tuple[str, int, bool]] = []  # (status, rows held, partial)
    deadline = time.monotonic() + 120
    while True:
        r = http.get(f"/v1/jobs/{job['id']}/observables", params={"start": len(
            held.get("step", []))})
        assert r.status_code == 200, r.text
        body = r.json()
        assert r.headers["Observables-Partial"] == ("true" if body["partial"] else "false")
        for k, v in body["observables"].items():
            held.setdefault(k, []).extend(v)
        seen.append((body["status"], len(held.get("step", [])), body["partial"]))
        if not body["partial"]:
            break
        assert time.monotonic() < deadline, seen[-3:]
        time.sleep(0.05)
    assert seen[-1][0] == "succeeded"
    running = sorted({rows for st, rows, partial in seen if partial and rows > 0})
    assert len(running) >= 2, seen  # grew while the job ran
    final = _final_csv(server, job["id"])
    assert list(held) == list(final)
    for k, v in final.items():
        assert np.array_equal(np.array(held[k], dtype=float), v, equal_nan=True), k
    # all at once, and through the client, once it has ended: the same series
    with Client(server.url, transport=server.transport) as c:
        got = c.job(job["id"]).observables()
    assert got["partial"] is False and got["status"] == "succeeded"
    for k, v in final.items():
        assert np.array_equal(got["observables"][k], v, equal_nan=True), k


@pytest.mark.slow
def test_client_reads_a_running_job_and_pages(server, http):
    spec = scenario(n=100, steps=60_000, every=0)
    spec["recording"]["observables_every"] = 10
    job = submit(http, spec)
    with Client(server.url, transport=server.transport) as c:
        handle = c.job(job["id"])
        deadline = time.monotonic() + 120
        while True:
            now = handle.observables()
            if now["partial"] and len(now["observables"].get("step", [])) > 0:
                break
            assert now["partial"], "the job ended before any row was seen running"
            assert time.monotonic() < deadline
            time.sleep(0.2)
        assert now["status"] == "running"
        steps = now["observables"]["step"]
        assert steps[0] == 0 and np.all(np.diff(steps) == 10)
        # a small page says there is more; the next page starts where it stopped
        page = http.get(f"/v1/jobs/{job['id']}/observables",
                        params={"start": 1, "limit": 1}).json()
        assert page["rows"] == 1 and page["observables"]["step"] == [10.0]
        assert page["more"] is True or len(steps) == 2
        assert wait_for(http, job["id"], timeout=120)["status"] == "succeeded"
        final = handle.observables()
        assert final["partial"] is False
        n = len(steps)
        assert np.array_equal(final["observables"]["step"][:n], steps)
        assert np.array_equal(final["observables"]["polarization"][:n],
                              now["observables"]["polarization"])


def test_observables_route_errors(server, http):
    missing = "00000000-0000-4000-8000-000000000000"
    assert_problem(http.get(f"/v1/jobs/{missing}/observables"), 404)
    job = submit(http, scenario(n=50, steps=10, every=5))
    assert_problem(http.get(f"/v1/jobs/{job['id']}/observables", params={"start": -1}),
                   422, "query.start")
    assert_problem(http.get(f"/v1/jobs/{job['id']}/observables", params={"limit": 0}),
                   422, "query.limit")
    assert_problem(http.get("/v1/jobs/not-a-uuid/observables"), 422)
    # a finished job whose observables.csv went missing from its results: 500, not rows
    assert wait_for(http, job["id"])["status"] == "succeeded"
    (Path(server.data_dir) / "results" / job["id"] / "observables.csv").unlink()
    body = assert_problem(http.get(f"/v1/jobs/{job['id']}/observables"), 500)
    assert body["type"].endswith(":results-corrupted")
