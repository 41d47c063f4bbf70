"""Sweeps and pictures under hostile input (issue 28), on a real server on 127.0.0.1 with
real spawned workers: each test is one finding of the loopback attack, and failed on the
code before its fix."""

from __future__ import annotations

import json
import os
import signal
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from tests.service.inproc import InProcessServer
from tests.service.svc_helpers import assert_problem, scenario, wait_for
from tests.service.svc_helpers import submit as submit_job
from tests.service.sweeps.test_sweeps import SWEEP_ENV, _worker_pids, submit, sweep_spec, wait_sweep


@pytest.fixture(scope="module")
def hostile_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[InProcessServer]:
    # Bodies up to 4 MiB: room for the 1.1 MB attack body.
    env = {**SWEEP_ENV, "FLOCKLAB_MAX_BODY_BYTES": str(4 * 2**20),
           "FLOCKLAB_MAX_JSON_BYTES": str(4 * 2**20)}
    s = InProcessServer(tmp_path_factory.mktemp("hostile") / "data", env=env).start()
    try:
        yield s
    finally:
        s.stop()


@pytest.fixture
def http(hostile_server: InProcessServer) -> Iterator[httpx.Client]:
    with hostile_server.client(timeout=60) as c:
        yield c


def _table(http: httpx.Client, sweep_id: str, name: str) -> dict[str, Any]:
    r = http.get(f"/v1/sweeps/{sweep_id}/{name}", params={"format": "json"})
    assert r.status_code == 200, r.text
    return r.json()


@pytest.mark.slow
def test_a_replicas_axis_runs(http: httpx.Client):
    """A `replicas` axis was accepted (202), then the worker refused its own stored form
    ("give 'replicas' either as a field or as an axis") and the sweep always failed."""
    from flocklab.schemas.sweep import Sweep

    spec = sweep_spec(etas=(0.5, 2.0), name="replicas-axis")
    del spec["replicas"]
    spec["axes"].append({"path": "replicas", "values": [1, 2]})
    created = submit(http, spec)
    assert created["runs_total"] == 6  # 2 etas x (1 + 2) replicas
    done = wait_sweep(http, created["id"])
    assert done["status"] == "succeeded", done
    assert (done["runs_done"], done["runs_failed"]) == (6, 0)
    table = _table(http, created["id"], "table")
    count = table["columns"].index("va_count")
    assert [row[count] for row in table["data"]] == [1, 2, 1, 2]
    stored = http.get(f"/v1/sweeps/{created['id']}/spec").content
    assert Sweep.model_validate_json(stored).n_runs == 6  # the stored form validates


@pytest.mark.slow
def test_b_no_server_path_in_the_sweep_plots_problem(http: httpx.Client,
                                                     hostile_server: InProcessServer):
    """Plotting a sweep without axes answered 422 "<the results folder>: the sweep has no
    rows or no axes", the server's data path in the body."""
    pytest.importorskip("matplotlib")
    spec = sweep_spec(etas=(1.0,), replicas=1, name="no-axes")
    spec["axes"] = []
    done = wait_sweep(http, submit(http, spec)["id"])
    assert done["status"] == "succeeded", done
    r = http.get(f"/v1/sweeps/{done['id']}/render/plot.png", timeout=120)
    body = assert_problem(r, 422)
    assert "no rows or no axes" in body["detail"]
    data = hostile_server.data_dir
    for root in {str(data), str(data.resolve()), str(data.parent)}:
        assert root not in r.text


@pytest.mark.slow
def test_c_render_parameters_and_empty_observables_are_4xx(http: httpx.Client,
                                                           tmp_path: Path):
    """movie.mp4?fps=1e-300 reached the encoder as "-r 0" (a 500); observables.png of a
    job recorded with `observables: []` asked matplotlib for 0 panels (a 500)."""
    pytest.importorskip("matplotlib")
    job = submit_job(http, scenario(n=30, steps=20, every=5))
    assert wait_for(http, job["id"])["status"] == "succeeded"
    movie = f"/v1/jobs/{job['id']}/render/movie.mp4"
    for fps in (1e-300, 0.01, 0.0999, 121):
        assert_problem(http.get(movie, params={"fps": fps}), 422, "query.fps")
    slow = http.get(movie, params={"fps": 0.1, "width": 64, "height": 64}, timeout=120)
    assert slow.status_code == 200, slow.text
    assert slow.content[4:8] == b"ftyp"
    (tmp_path / "slow.mp4").write_bytes(slow.content)
    import imageio.v2 as imageio

    with imageio.get_reader(tmp_path / "slow.mp4", format="FFMPEG") as reader:
        assert reader.count_frames() == 5  # frames at steps 0, 5, .., 20
        assert reader.get_meta_data()["fps"] == pytest.approx(0.1)

    body = scenario(n=30, steps=20, every=5)
    body["recording"]["observables"] = []
    quiet = submit_job(http, body)
    assert wait_for(http, quiet["id"])["status"] == "succeeded"
    r = http.get(f"/v1/jobs/{quiet['id']}/render/observables.png", timeout=120)
    problem = assert_problem(r, 404)
    assert problem["type"].endswith("nothing-to-draw")
    assert "no observables were recorded" in problem["detail"]
    named = http.get(f"/v1/jobs/{quiet['id']}/render/observables.png",
                     params={"names": "polarization"}, timeout=120)
    assert_problem(named, 422, "query.names")


@pytest.mark.parametrize("change", [
    # runs.csv: the axis 'name' and the measure 'name' (table.csv read the wrong one)
    lambda s: (s["axes"].append({"path": "name", "values": ["a", "b"]}),
               s["measure"].update(name={"observable": "polarization", "reduce": "final"})),
    # series.csv: the axis 'time' and the fixed column 'time'
    lambda s: s["axes"].append({"path": "time", "values": [{"steps": 40}, {"steps": 60}]}),
])
def test_d_duplicate_column_names_are_refused(http: httpx.Client, change):
    """Sweeps whose tables would hold two columns of one name were accepted, their tables
    then ambiguous (a reader by name took one column for the other)."""
    spec = sweep_spec(etas=(1.0,), replicas=1, name="clash")
    change(spec)
    body = assert_problem(http.post("/v1/sweeps", json=spec), 422)
    assert "two columns named" in json.dumps(body)


def test_e_problem_bodies_are_bounded(http: httpx.Client):
    """Thousands of bad axes answered with an error each (571 KB bodies); a 200 KB preset
    name came back whole."""
    spec = sweep_spec(name="many-bad-axes")
    spec["axes"] = [{"zip": [{"path": f"model.p{j}", "values": []} for j in range(64)]}
                    for _ in range(64)]
    r = http.post("/v1/sweeps", json=spec)
    body = assert_problem(r, 422)
    assert len(body["errors"]) == 20 and body["errors_total"] == 64 * 64
    assert [e["loc"] for e in body["errors"]] == [f"axes.0.zip.{j}.values" for j in range(20)]
    assert len(r.content) < 8_000

    r = http.post("/v1/sweeps", json={**sweep_spec(), "base": None, "preset": "x" * 200_000})
    body = assert_problem(r, 422, "preset")
    assert len(r.content) < 8_000
    assert "more characters)" in body["errors"][0]["msg"]


def _timed_post(http: httpx.Client, body: bytes) -> tuple[httpx.Response, float]:
    t0 = time.monotonic()
    r = http.post("/v1/sweeps", content=body, headers={"Content-Type": "application/json"})
    return r, time.monotonic() - t0


def test_f_many_axes_answered_in_under_a_second(http: httpx.Client):
    """The axis-overlap check compared every pair of paths: a 1.1 MB body (28,000 axes)
    cost 92 s of CPU before its 422."""
    spec = sweep_spec(name="many-axes")
    spec["axes"] = [{"path": f"model.p{i}", "values": [1]} for i in range(28_000)]
    raw = json.dumps(spec).encode()
    assert len(raw) > 1_100_000
    r, seconds = _timed_post(http, raw)
    assert_problem(r, 422, "axes")
    assert seconds < 1.0, seconds

    # The most entries the limits allow (64 zip axes of 64 paths), the last two overlapping:
    # every pair is looked at, and the overlap is found.
    spec["axes"] = [{"zip": [{"path": f"model.p{i}.q{j}", "values": [1]} for j in range(64)]}
                    for i in range(64)]
    spec["axes"][-1]["zip"][-1]["path"] = "model.p0"
    r, seconds = _timed_post(http, json.dumps(spec).encode())
    body = assert_problem(r, 422)
    assert "'model.p0.q0' and 'model.p0' overlap" in json.dumps(body)
    assert seconds < 1.0, seconds


@pytest.fixture(scope="module")
def long_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[InProcessServer]:
    """Runs of 0.2-0.6 s (N = 1000, 3000 steps), one worker: a sweep of 12 lasts seconds."""
    env = {**SWEEP_ENV, "FLOCKLAB_MAX_SWEEP_AGENT_STEPS": "50000000"}
    s = InProcessServer(tmp_path_factory.mktemp("hostile-long") / "data", env=env).start()
    try:
        yield s
    finally:
        s.stop()


def _kill_worker(server: InProcessServer) -> None:
    workers = _worker_pids(server)
    assert len(workers) == 1
    os.kill(workers[0], signal.SIGKILL)


def _assert_runs_kept(http: httpx.Client, server: InProcessServer, done: dict[str, Any]
                      ) -> None:
    """The sweep's finished runs are its results, each once, in the journal and tables."""
    assert done["results"] == "available", done
    runs = _table(http, done["id"], "runs")
    status = runs["columns"].index("status")
    completed = [row for row in runs["data"] if row[status] == "completed"]
    assert len(runs["data"]) == 12 and len(completed) == done["runs_done"] >= 1
    journal = [json.loads(line) for line in (server.data_dir / "results" / done["id"] /
                                             "runs.jsonl").read_text().splitlines()
               if line.strip()]
    assert sorted({r["run"] for r in journal}) == sorted(row[0] for row in completed)
    table = _table(http, done["id"], "table")
    count = table["columns"].index("va_count")
    assert sum(row[count] for row in table["data"]) == len(completed)


@pytest.mark.slow
def test_k_a_second_worker_loss_keeps_the_finished_runs(long_server: InProcessServer):
    """Losing the worker on the last allowed attempt failed the sweep and deleted every
    run it had finished."""
    with long_server.client(timeout=60) as http:
        created = submit(http, sweep_spec(etas=(0.5, 1.0, 2.0, 3.0), replicas=3, n=1000,
                                          steps=3000, name="lost-twice"))
        first = wait_sweep(http, created["id"], until=lambda s: s["runs_done"] >= 2)
        _kill_worker(long_server)
        wait_sweep(http, created["id"], until=lambda s: s["attempts"] == 2 and s[
            "status"] == "running" and s["runs_done"] > first["runs_done"])
        _kill_worker(long_server)
        done = wait_sweep(http, created["id"])
        assert done["status"] == "failed" and done["error"]["type"].endswith("worker-lost")
        assert first["runs_done"] < done["runs_done"] < 12
        _assert_runs_kept(http, long_server, done)


@pytest.mark.slow
def test_k_a_cancel_then_a_worker_death_keeps_the_finished_runs(long_server: InProcessServer):
    """A cancel followed by the worker's death (before it wrote its tables) deleted the
    runs the sweep had finished."""
    with long_server.client(timeout=60) as http:
        created = submit(http, sweep_spec(etas=(0.5, 1.0, 2.0, 3.0), replicas=3, n=1000,
                                          steps=3000, name="cancel-kill"))
        wait_sweep(http, created["id"], until=lambda s: s["runs_done"] >= 1)
        assert http.post(f"/v1/sweeps/{created['id']}/cancel").status_code == 202
        _kill_worker(long_server)
        done = wait_sweep(http, created["id"])
        assert done["status"] == "cancelled"
        _assert_runs_kept(http, long_server, done)


def _peak_rss_mib(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    raise AssertionError("no VmHWM")


@pytest.mark.slow
def test_g_admitting_a_max_size_sweep_takes_bounded_memory(make_server):
    """Checking a 10^5-run sweep held every expanded run (a validated scenario each):
    bench/sweep_admission_memory.py measured +149 MiB of peak RSS for it before the runs
    were checked one at a time, +1 MiB after; the server's peak grows ~31 MiB here."""
    s = make_server({"FLOCKLAB_MAX_SWEEP_RUNS": "100000",
                     "FLOCKLAB_MAX_SWEEP_AGENT_STEPS": str(10**12),
                     "FLOCKLAB_MAX_BODY_BYTES": str(4 * 2**20),
                     "FLOCKLAB_MAX_JSON_BYTES": str(4 * 2**20),
                     "FLOCKLAB_MAX_QUEUED": "100"})
    assert s.proc is not None
    before = _peak_rss_mib(s.proc.pid)
    spec = sweep_spec(etas=tuple(round(i * 5e-5, 6) for i in range(100_000)), replicas=1,
                      name="max-size")
    with httpx.Client(base_url=s.url, timeout=120) as http:
        # Queued behind a job holding the worker, so only the API's admission is measured.
        blocker = submit_job(http, scenario(n=1000, steps=100_000, every=0))
        created = submit(http, spec)
        assert created["runs_total"] == 100_000
        peak = _peak_rss_mib(s.proc.pid)
        for job in (f"/v1/sweeps/{created['id']}", f"/v1/jobs/{blocker['id']}"):
            http.post(f"{job}/cancel")
    assert peak - before < 75, (before, peak)
