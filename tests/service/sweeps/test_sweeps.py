"""Sweeps over HTTP on the real app (in-process: real SQLite store, real spawned workers):
the table equals the local runner's, progress over SSE, cancel, limits and bad input as
problem+json, idempotency, and a worker killed mid-sweep."""

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

from flocklab.service.serve import ServerProcess
from tests.service.conftest import TEST_ENV
from tests.service.inproc import InProcessServer
from tests.service.svc_helpers import assert_problem

# Small sweep limits to test against: 12 runs, 10^6 agent-steps.
# One run per engine call, so cancels and kills land between runs (the engine would fuse
# a whole batch of these small runs into one launch that ends all of them together).
SWEEP_ENV = {**TEST_ENV, "FLOCKLAB_MAX_SWEEP_RUNS": "12",
             "FLOCKLAB_MAX_SWEEP_AGENT_STEPS": "1000000", "FLOCKLAB_SWEEP_BATCH_RUNS": "1"}


def sweep_spec(etas: tuple[float, ...] = (0.5, 2.0), replicas: int = 2, n: int = 40,
               steps: int = 60, name: str = "eta-scan") -> dict[str, Any]:
    """A Vicsek η scan at density 4 (N agents in a box of side sqrt(N / 4))."""
    return {
        "name": name,
        "base": {
            "model": {"kind": "vicsek", "rule": "vicsek", "v0": 0.03},
            "space": {"kind": "periodic", "L": (n / 4) ** 0.5},
            "neighbours": {"radius": 1.0},
            "initial": {"kind": "random", "N": n},
            "time": {"steps": steps},
            "recording": {"every": 0, "observables_every": 5},
            "seed": 11,
        },
        "axes": [{"path": "model.eta", "values": list(etas)}],
        "replicas": replicas,
        "measure": {"va": {"observable": "polarization", "reduce": "mean", "from_step": 20}},
        "series": ["polarization"],
    }


@pytest.fixture(scope="module")
def sweep_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[InProcessServer]:
    s = InProcessServer(tmp_path_factory.mktemp("sweeps") / "data", env=SWEEP_ENV).start()
    try:
        yield s
    finally:
        s.stop()


@pytest.fixture(scope="module")
def long_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[InProcessServer]:
    """A server admitting runs long enough (0.1-0.3 s each) to cancel or kill a sweep in
    the middle: on the fused path a whole sweep within SWEEP_ENV's 10^6 agent-steps takes
    about 0.1 s, less than a poll can be sure to catch."""
    env = {**SWEEP_ENV, "FLOCKLAB_MAX_SWEEP_AGENT_STEPS": "20000000"}
    s = InProcessServer(tmp_path_factory.mktemp("long") / "data", env=env).start()
    try:
        yield s
    finally:
        s.stop()


@pytest.fixture
def long_http(long_server: InProcessServer) -> Iterator[httpx.Client]:
    with long_server.client(timeout=30) as c:
        yield c


@pytest.fixture
def http(sweep_server: InProcessServer) -> Iterator[httpx.Client]:
    with sweep_server.client(timeout=30) as c:
        yield c


def submit(http: httpx.Client, body: dict[str, Any], **kw: Any) -> dict[str, Any]:
    r = http.post("/v1/sweeps", json=body, **kw)
    assert r.status_code == 202, r.text
    assert r.headers["location"] == f"/v1/sweeps/{r.json()['id']}"
    return r.json()


def wait_sweep(http: httpx.Client, sweep_id: str, until: Any = None, timeout: float = 120.0
               ) -> dict[str, Any]:
    """Long-poll until `until(sweep)` holds (default: the sweep has finished)."""
    deadline = time.monotonic() + timeout
    while True:
        params = {"wait": 2, "until": "change"} if until else {"wait": 2}
        s = http.get(f"/v1/sweeps/{sweep_id}", params=params).json()
        if (until(s) if until else s["status"] in ("succeeded", "failed", "cancelled",
                                                    "timed_out")):
            return s
        assert time.monotonic() < deadline, f"sweep still {s['status']} after {timeout} s"


@pytest.mark.slow
def test_sweep_table_equals_the_local_runners(http: httpx.Client, tmp_path: Path):
    from flocklab.schemas.sweep import Sweep
    from flocklab.service.sweeps.runner import run_sweep
    from flocklab.service.sweeps.tables import read_table

    spec = sweep_spec()
    created = submit(http, spec)
    assert created["status"] == "queued" and created["runs_total"] == 4
    assert created["name"] == "eta-scan" and created["model"] == "vicsek"
    done = wait_sweep(http, created["id"])
    assert done["status"] == "succeeded", done
    assert (done["runs_done"], done["runs_failed"], done["progress"]) == (4, 0, 1.0)
    assert done["results"] == "available" and "table.csv" in done["checksums"]

    local = tmp_path / "local"
    outcome = run_sweep(Sweep.model_validate_json(json.dumps(spec)), local)
    assert (outcome.status, outcome.runs_done) == ("completed", 4)
    base = f"/v1/sweeps/{created['id']}"
    for name in ("table", "runs", "series"):
        r = http.get(f"{base}/{name}", params={"format": "csv"})
        assert r.status_code == 200 and r.headers["content-type"].startswith("text/csv")
        assert r.content == (local / f"{name}.csv").read_bytes(), name
    stored = http.get(f"{base}/spec").json()
    assert stored == Sweep.model_validate_json(json.dumps(spec)).model_dump(mode="json")
    as_json = http.get(f"{base}/table", headers={"Accept": "application/json"}).json()
    assert as_json["sweep_id"] == created["id"]
    assert {k: as_json[k] for k in ("columns", "data")} == read_table(local, "json")
    assert [row[1] for row in as_json["data"]] == [0.5, 2.0]  # one row per grid point
    pytest.importorskip("matplotlib")
    plot = http.get(f"{base}/render/plot.png", params={"width": 400, "height": 300},
                    timeout=120)
    assert plot.status_code == 200, plot.text
    assert plot.headers["content-type"] == "image/png"
    import imageio.v3 as iio

    img = iio.imread(plot.content)
    assert img.shape[:2] == (300, 400) and img.std() > 5  # a drawn plot, not blank
    assert http.get(f"{base}/table").headers["content-type"].startswith("text/csv")

    # Sweeps are listed apart from jobs, and a sweep is not a job.
    listed = http.get("/v1/sweeps", params={"status": "succeeded"}).json()["items"]
    assert created["id"] in [s["id"] for s in listed]
    assert created["id"] not in [j["id"] for j in http.get("/v1/jobs").json()["items"]]
    assert_problem(http.get(f"/v1/jobs/{created['id']}"), 404)


def test_progress_over_sse(http: httpx.Client):
    created = submit(http, sweep_spec(etas=(1.0,), replicas=3, name="sse"))
    events: list[tuple[str, dict]] = []
    with http.stream("GET", f"/v1/sweeps/{created['id']}/events", timeout=120) as r:
        assert r.headers["content-type"].startswith("text/event-stream")
        kind = None
        for line in r.iter_lines():
            if line.startswith("event: "):
                kind = line[len("event: "):]
            elif line.startswith("data: ") and kind:
                events.append((kind, json.loads(line[len("data: "):])))
                if kind == "end":
                    break
    assert events[-1][0] == "end"
    states = [e for k, e in events if k == "sweep"]
    assert states[-1]["status"] == "succeeded" and states[-1]["runs_done"] == 3
    done_counts = [s["runs_done"] for s in states]
    assert done_counts == sorted(done_counts) and all(s["runs_total"] == 3 for s in states)


@pytest.mark.slow
def test_cancel_keeps_the_finished_runs(long_http: httpx.Client):
    http = long_http
    # 12 runs of 1.5e6 agent-steps (0.1-0.3 s each): long enough to cancel in the middle.
    long = submit(http, sweep_spec(etas=(0.5, 1.0, 2.0, 3.0), replicas=3, n=1000, steps=1500,
                                   name="long"))
    queued = submit(http, sweep_spec(name="queued"))  # one worker: waits behind `long`
    wait_sweep(http, long["id"], until=lambda s: s["runs_done"] >= 1)

    q = http.post(f"/v1/sweeps/{queued['id']}/cancel")
    assert q.status_code == 202 and q.json()["status"] == "cancelled"
    r = http.post(f"/v1/sweeps/{long['id']}/cancel")
    assert r.status_code == 202 and r.json()["cancel_requested"]
    done = wait_sweep(http, long["id"], timeout=60)
    assert done["status"] == "cancelled" and 1 <= done["runs_done"] < 12
    assert done["results"] == "available"
    runs = http.get(f"/v1/sweeps/{long['id']}/runs", params={"format": "json"}).json()
    status_col = runs["columns"].index("status")
    completed = [row for row in runs["data"] if row[status_col] == "completed"]
    assert len(completed) >= 1 and len(runs["data"]) == 12

    never = http.get(f"/v1/sweeps/{queued['id']}").json()
    assert never["status"] == "cancelled" and never["attempts"] == 0
    assert_problem(http.get(f"/v1/sweeps/{queued['id']}/table"), 404)
    again = assert_problem(http.post(f"/v1/sweeps/{long['id']}/cancel"), 409)
    assert again["type"].endswith("sweep-finished") and again["status_now"] == "cancelled"
    finished = wait_sweep(http, submit(http, sweep_spec(etas=(1.0,), replicas=1))["id"])
    body = assert_problem(http.post(f"/v1/sweeps/{finished['id']}/cancel"), 409)
    assert body["type"].endswith("sweep-finished")


def test_limits_and_bad_input_are_problems(http: httpx.Client):
    too_many = sweep_spec(etas=(0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5), replicas=2)  # 14 runs
    body = assert_problem(http.post("/v1/sweeps", json=too_many), 422, "axes")
    assert body["type"].endswith("limit-exceeded")
    assert (body["runs"], body["max_runs"]) == (14, 12)

    named = http.post("/v1/sweeps", json={"sweep_preset": "vicsek-1995-fig2a"})
    assert assert_problem(named, 422, "axes")["runs"] == 140  # the named sweep, expanded

    heavy = sweep_spec(n=1000, steps=600)  # 4 runs x 1000 x 600 = 2.4e6 agent-steps
    body = assert_problem(http.post("/v1/sweeps", json=heavy), 422, "axes")
    assert (body["agent_steps"], body["max_agent_steps"]) == (2_400_000, 1_000_000)

    big_run = sweep_spec(replicas=1)
    big_run["axes"] = [{"zip": [{"path": "initial.N", "values": [100, 6000]},
                                {"path": "space.L", "values": [5.0, 38.0]}]}]
    big_run["base"]["time"]["steps"] = 30
    body = assert_problem(http.post("/v1/sweeps", json=big_run), 422, "runs[1].initial.N")
    assert "5000" in body["detail"]

    unknown = sweep_spec()
    unknown["axes"] = [{"path": "model.etaa", "values": [1.0]}]
    assert_problem(http.post("/v1/sweeps", json=unknown), 422, "axes.0.path")

    bad_value = sweep_spec(etas=(1.0, -1.0))
    body = assert_problem(http.post("/v1/sweeps", json=bad_value), 422)
    assert any(e["loc"].startswith("runs[2].") and e["loc"].endswith("model.eta")
               for e in body["errors"]), body["errors"]

    unequal = sweep_spec()
    unequal["axes"] = [{"zip": [{"path": "initial.N", "values": [100, 400]},
                                {"path": "space.L", "values": [5.0]}]}]
    assert "equal lengths" in assert_problem(http.post("/v1/sweeps", json=unequal), 422
                                             )["detail"]
    empty = sweep_spec(etas=())
    assert_problem(http.post("/v1/sweeps", json=empty), 422)
    extra = {**sweep_spec(), "colour": "red"}
    assert_problem(http.post("/v1/sweeps", json=extra), 422, "colour")
    assert_problem(http.post("/v1/sweeps", content=b'{"name": ', headers={
        "Content-Type": "application/json"}), 400)
    nan = json.dumps(sweep_spec()).replace('"v0": 0.03', '"v0": NaN')
    assert_problem(http.post("/v1/sweeps", content=nan.encode(), headers={
        "Content-Type": "application/json"}), 422)
    huge = json.dumps({**sweep_spec(), "description": "x" * 300_000}).encode()
    assert_problem(http.post("/v1/sweeps", content=huge, headers={
        "Content-Type": "application/json"}), 413)
    assert_problem(http.post("/v1/sweeps", json=[1, 2]), 422, "(root)")
    wrapped = {"sweep": sweep_spec(), "timeout_seconds": -1}
    assert_problem(http.post("/v1/sweeps", json=wrapped), 422, "timeout_seconds")
    assert_problem(http.get("/v1/sweeps/not-a-uuid"), 422)
    assert_problem(http.get("/v1/sweeps/00000000-0000-4000-8000-000000000000"), 404)


def test_an_observable_the_model_lacks_fails_the_sweep_before_its_runs(http: httpx.Client):
    spec = sweep_spec(etas=(1.0,), replicas=1, name="no-such-observable")
    spec["measure"]["va"]["observable"] = "vorticity"
    created = submit(http, spec)  # only the engine knows a model's observables
    done = wait_sweep(http, created["id"])
    assert done["status"] == "failed" and done["results"] == "none"
    assert done["error"]["type"].endswith("invalid-sweep")
    assert [e["loc"] for e in done["error"]["errors"]] == ["measure.va.observable"]
    assert done["attempts"] == 1  # bad input is never retried


def test_idempotency_key(http: httpx.Client):
    spec = sweep_spec(etas=(1.5,), replicas=1, name="idem")
    key = {"Idempotency-Key": f"sweep-{time.time_ns()}"}
    first = submit(http, spec, headers=key)
    again = http.post("/v1/sweeps", json=spec, headers=key)
    assert again.status_code == 202 and again.json()["id"] == first["id"]
    assert again.headers["idempotent-replayed"] == "true"
    other = sweep_spec(etas=(2.5,), replicas=1, name="idem")
    body = assert_problem(http.post("/v1/sweeps", json=other, headers=key), 409)
    assert body["job_id"] == first["id"]
    job = {"scenario": spec["base"]}
    assert_problem(http.post("/v1/jobs", json=job, headers=key), 409)
    ids = [s["id"] for s in http.get("/v1/sweeps", params={"limit": 500}).json()["items"]]
    assert ids.count(first["id"]) == 1
    wait_sweep(http, first["id"])


def _worker_pids(server: InProcessServer | ServerProcess) -> list[int]:
    pids = []
    for pid in server.children():
        try:
            if b"spawn_main" in Path(f"/proc/{pid}/cmdline").read_bytes():
                pids.append(pid)
        except OSError:
            pass
    return pids


@pytest.mark.slow
def test_worker_killed_mid_sweep_resumes_without_redoing_runs(
        long_http: httpx.Client, long_server: InProcessServer):
    http = long_http
    created = submit(http, sweep_spec(etas=(0.5, 1.5, 3.0), replicas=3, n=1000, steps=1500,
                                      name="killed"))
    before = wait_sweep(http, created["id"], until=lambda s: s["runs_done"] >= 2)
    assert before["status"] == "running"
    workers = _worker_pids(long_server)
    assert len(workers) == 1
    killed_at = time.time()
    os.kill(workers[0], signal.SIGKILL)
    done = wait_sweep(http, created["id"], timeout=180)
    assert done["status"] == "succeeded", done
    assert done["attempts"] == 2 and done["runs_done"] == done["runs_total"] == 9
    assert done["runs_failed"] == 0

    folder = long_server.data_dir / "results" / created["id"]
    journal = [json.loads(line) for line in (folder / "runs.jsonl").read_text().splitlines()
               if line.strip()]
    assert sorted(r["run"] for r in journal) == list(range(9))  # no run counted twice
    # The runs finished before the kill were not redone: their summaries predate it.
    early = [i for i in range(9)
             if (folder / "runs" / str(i) / "summary.json").stat().st_mtime < killed_at]
    assert len(early) >= before["runs_done"]
    table = http.get(f"/v1/sweeps/{created['id']}/table", params={"format": "json"}).json()
    count = table["columns"].index("va_count")
    assert [row[count] for row in table["data"]] == [3, 3, 3]


def test_openapi_describes_the_sweep_body(http: httpx.Client):
    doc = http.get("/openapi.json").json()
    assert "Sweep" in doc["components"]["schemas"]
    assert "axes" in doc["components"]["schemas"]["Sweep"]["properties"]
    body = doc["paths"]["/v1/sweeps"]["post"]["requestBody"]["content"]["application/json"]
    assert {"$ref": "#/components/schemas/Sweep"} in body["schema"]["oneOf"]
    assert "/v1/sweeps/{sweep_id}/table" in doc["paths"]


@pytest.mark.slow
def test_service_killed_mid_sweep_resumes_after_restart(make_server, tmp_path: Path):
    data = tmp_path / "data"
    # Runs of about half a second each, so the API is killed well before the sweep ends
    # (at 6e4 agent-steps a run, a slow poll could see the whole sweep finish first).
    env = {**SWEEP_ENV, "FLOCKLAB_MAX_SWEEP_AGENT_STEPS": "20000000"}
    s1 = make_server(env=env, data_dir=data)
    with httpx.Client(base_url=s1.url, timeout=30) as http:
        created = submit(http, sweep_spec(etas=(0.5, 3.0), replicas=3, n=1000, steps=1500,
                                          name="restart"))
        before = wait_sweep(http, created["id"], until=lambda s: s["runs_done"] >= 2)
    killed_at = time.time()
    s1.kill()  # kill -9 the API; its orphaned worker stops by itself

    s2 = make_server(env=env, data_dir=data)
    with httpx.Client(base_url=s2.url, timeout=30) as http:
        done = wait_sweep(http, created["id"], timeout=180)
        assert done["status"] == "succeeded" and done["attempts"] == 2
        assert done["runs_done"] == 6
        assert [s["id"] for s in http.get("/v1/sweeps").json()["items"]] == [created["id"]]
    folder = data / "results" / created["id"]
    early = [i for i in range(6)
             if (folder / "runs" / str(i) / "summary.json").stat().st_mtime < killed_at]
    assert len(early) >= before["runs_done"]
    assert not list((data / "results" / ".attempts").iterdir())
