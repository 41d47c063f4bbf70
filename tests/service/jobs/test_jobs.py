"""The job API on the real app (in-process): submit, follow, results, cancel, timeout,
idempotency."""

from __future__ import annotations

import base64
import hashlib
import io
import json
import time
import uuid

import h5py
import numpy as np
import pytest

from tests.service.svc_helpers import assert_problem, long_scenario, scenario, submit, wait_for


@pytest.fixture(scope="module")
def finished(server):
    """One succeeded job with frames 0, 5, ..., 40 of 120 agents."""

    with server.client(timeout=30) as http:
        job = submit(http, {"scenario": scenario(n=120, steps=40, every=5)})
        done = wait_for(http, job["id"], timeout=120)
    assert done["status"] == "succeeded", done
    return done


def _h5(server, job_id: str) -> h5py.File:
    return h5py.File(server.data_dir / "results" / job_id / "trajectory.h5", "r")


def test_submit_answers_202_with_location_and_runs_to_completion(http):
    r = http.post("/v1/jobs", json={"scenario": scenario()})
    assert r.status_code == 202
    job = r.json()
    assert r.headers["location"] == f"/v1/jobs/{job['id']}"
    assert uuid.UUID(job["id"]).version == 4
    assert job["status"] in ("queued", "running")
    done = wait_for(http, job["id"])
    assert done["status"] == "succeeded"
    assert done["progress"] == 1.0 and done["steps_done"] == 20
    assert done["backend"] == "cpu" and done["attempts"] == 1
    assert done["started_at"] >= done["created_at"] and done["finished_at"] >= done["started_at"]
    assert done["results"] == "available" and done["error"] is None


def test_bare_scenario_and_preset_bodies(http):
    bare = submit(http, scenario(steps=3))
    assert wait_for(http, bare["id"])["status"] == "succeeded"
    pre = submit(http, {"preset": "vicsek-1995", "overrides": {"time": {"steps": 5},
                                                                "initial": {"N": 50}}})
    assert pre["n_agents"] == 50 and pre["steps_total"] == 5
    assert wait_for(http, pre["id"])["status"] == "succeeded"


def test_metrics_are_the_runs_observables(http, finished):
    m = http.get(f"/v1/jobs/{finished['id']}/metrics").json()
    assert m["summary"]["status"] == "completed" and m["summary"]["n_agents"] == 120
    obs = m["observables"]
    assert obs["step"][0] == 0 and len(obs["step"]) == len(obs["polarization"])
    assert all(0 <= p <= 1 for p in obs["polarization"])


def test_trajectory_slices_match_the_h5md_file(http, server, finished):
    job_id = finished["id"]
    with _h5(server, job_id) as f:
        pos = f["particles/swarm/position/value"][:]
        steps = f["particles/swarm/position/step"][:]
    assert pos.shape == (9, 120, 2)

    r = http.get(f"/v1/jobs/{job_id}/trajectory", params={"start": 1, "stop": 8, "stride": 3,
                                                           "agents": "10:40:5"})
    assert r.headers["content-type"] == "application/x-npz"
    z = np.load(io.BytesIO(r.content), allow_pickle=False)
    np.testing.assert_array_equal(z["position"], pos[1:8:3, 10:40:5])
    np.testing.assert_array_equal(z["step"], steps[1:8:3])
    np.testing.assert_array_equal(z["agents"], np.arange(10, 40, 5))
    assert z["heading"].shape == (3, 6)

    r = http.get(f"/v1/jobs/{job_id}/trajectory",
                 params={"format": "json", "agents": "7,3,99", "arrays": "position",
                         "start": -2})
    body = r.json()
    assert set(body) == {"job_id", "step", "time", "agents", "position"}
    np.testing.assert_array_equal(np.array(body["position"]), pos[-2:][:, [7, 3, 99]])


def test_trajectory_bad_slices(http, finished):
    url = f"/v1/jobs/{finished['id']}/trajectory"
    assert_problem(http.get(url, params={"agents": "1,1"}), 422, "query.agents")
    assert_problem(http.get(url, params={"agents": "5,120"}), 422, "query.agents")
    assert_problem(http.get(url, params={"arrays": "velocity"}), 422, "query.arrays")
    assert_problem(http.get(url, params={"stride": 0}), 422, "query.stride")
    assert_problem(http.get(url, params={"format": "csv"}), 422, "query.format")


def test_large_json_slices_are_413(http):
    # 1000 agents x 3 values x 21 frames x ~24 B > the 256 KiB JSON cap of the tests.
    job = submit(http, {"scenario": scenario(n=1000, steps=20, every=1)})
    assert wait_for(http, job["id"])["status"] == "succeeded"
    url = f"/v1/jobs/{job['id']}/trajectory"
    assert_problem(http.get(url, params={"format": "json"}), 413)
    assert http.get(url, params={"format": "json", "agents": "0:10"}).status_code == 200
    z = np.load(io.BytesIO(http.get(url).content))
    assert z["position"].shape == (21, 1000, 2)


def test_h5_download_streams_with_range_and_digest(http, server, finished):
    url = f"/v1/jobs/{finished['id']}/trajectory.h5"
    r = http.get(url)
    assert r.status_code == 200 and r.headers["accept-ranges"] == "bytes"
    digest = base64.b64encode(hashlib.sha256(r.content).digest()).decode()
    assert r.headers["repr-digest"] == f"sha-256=:{digest}:"
    assert finished["checksums"]["trajectory.h5"] == hashlib.sha256(r.content).hexdigest()
    part = http.get(url, headers={"Range": "bytes=0-7"})
    assert part.status_code == 206 and part.content == r.content[:8] == b"\x89HDF\r\n\x1a\n"


def test_results_of_unfinished_and_unknown_jobs(http):
    job = submit(http, {"scenario": long_scenario()})
    try:
        body = assert_problem(http.get(f"/v1/jobs/{job['id']}/metrics"), 409)
        assert body["status_now"] in ("queued", "running")
    finally:
        http.post(f"/v1/jobs/{job['id']}/cancel")
    missing = uuid.uuid4()
    assert_problem(http.get(f"/v1/jobs/{missing}"), 404)
    assert_problem(http.get(f"/v1/jobs/{missing}/metrics"), 404)
    assert_problem(http.post(f"/v1/jobs/{missing}/cancel"), 404)


@pytest.mark.parametrize("path", [
    "/v1/jobs/..%2F..%2Fjobs.sqlite3/metrics",
    "/v1/jobs/%2E%2E/trajectory.h5",
    "/v1/jobs/..%2Fresults/trajectory",
    "/v1/jobs/00000000-0000-0000-0000-000000000000%2F..%2F..%2Fjobs.sqlite3/metrics",
])
def test_no_path_traversal(http, path):
    r = http.get(path)
    assert r.status_code in (404, 422), r.text
    assert r.headers["content-type"].startswith("application/problem+json")
    assert b"SQLite" not in r.content


def test_cancel_a_running_job_within_seconds(http):
    job = submit(http, {"scenario": long_scenario()})
    wait_for(http, job["id"], {"running"})
    t0 = time.monotonic()
    r = http.post(f"/v1/jobs/{job['id']}/cancel")
    assert r.status_code == 202 and r.json()["cancel_requested"]
    done = wait_for(http, job["id"], timeout=15)
    assert done["status"] == "cancelled"
    assert time.monotonic() - t0 < 5
    assert done["steps_done"] < 100_000
    # Cancelling a cancelled job is 409 like any finished job; the state stays final (R4).
    again = assert_problem(http.post(f"/v1/jobs/{job['id']}/cancel"), 409)
    assert again["status_now"] == "cancelled"
    assert http.get(f"/v1/jobs/{job['id']}").json()["status"] == "cancelled"


def test_a_cancelled_queued_job_never_starts(http):
    blocker = submit(http, {"scenario": long_scenario()})
    queued = submit(http, {"scenario": scenario()})
    try:
        r = http.post(f"/v1/jobs/{queued['id']}/cancel")
        assert r.json()["status"] == "cancelled"
    finally:
        http.post(f"/v1/jobs/{blocker['id']}/cancel")
    wait_for(http, blocker["id"])
    time.sleep(0.5)
    job = http.get(f"/v1/jobs/{queued['id']}").json()
    assert job["status"] == "cancelled" and job["attempts"] == 0 and job["started_at"] is None


def test_finished_jobs_cannot_be_cancelled(http, finished):
    body = assert_problem(http.post(f"/v1/jobs/{finished['id']}/cancel"), 409)
    assert body["status_now"] == "succeeded"
    assert http.get(f"/v1/jobs/{finished['id']}").json()["status"] == "succeeded"


@pytest.mark.slow
def test_timeout_ends_as_timed_out(http):
    job = submit(http, {"scenario": long_scenario(), "timeout_seconds": 1.5})
    done = wait_for(http, job["id"], timeout=30)
    assert done["status"] == "timed_out"
    assert done["error"]["type"].endswith("timeout") and done["error"]["timeout_seconds"] == 1.5
    assert done["finished_at"] is not None


@pytest.mark.slow
def test_a_diverging_run_fails_with_its_step_and_cause_and_keeps_its_frames(http):
    # Two agents at the same point: the pair force is infinite at the first step. (A
    # runaway speed such as v0 = 1e300 is now refused at admission: test_hardening_input.)
    body = {"model": {"kind": "flocking"}, "space": {"kind": "plane"},
            "neighbours": {"radius": 2.0},
            "initial": {"kind": "explicit", "positions": [[0, 0], [0, 0], [1, 0]]},
            "time": {"steps": 50, "dt": 0.01}, "recording": {"every": 1}}
    done = wait_for(http, submit(http, {"scenario": body})["id"])
    assert done["status"] == "failed" and done["attempts"] == 1  # never retried
    err = done["error"]
    assert err["type"].endswith("diverged") and err["step"] <= 2
    assert err["cause"] and err["quantity"].startswith("position")
    assert done["results"] == "available"  # the frames before the blow-up are kept
    m = http.get(f"/v1/jobs/{done['id']}/metrics").json()
    assert m["summary"]["status"] == "diverged"


def test_idempotency_key(http):
    body = {"scenario": scenario(steps=4)}
    key = {"Idempotency-Key": f"test-{uuid.uuid4()}"}
    first = http.post("/v1/jobs", json=body, headers=key)
    again = http.post("/v1/jobs", json=body, headers=key)
    assert first.status_code == again.status_code == 202
    assert first.json()["id"] == again.json()["id"]
    assert again.headers["idempotent-replayed"] == "true"
    # The same scenario written differently (defaults spelled out) is the same request.
    spelled = {"scenario": {**scenario(steps=4), "backend": "cpu"}}
    assert http.post("/v1/jobs", json=spelled, headers=key).json()["id"] == first.json()["id"]
    other = http.post("/v1/jobs", json={"scenario": scenario(steps=5)}, headers=key)
    assert assert_problem(other, 409)["job_id"] == first.json()["id"]
    listed = [j["id"] for j in http.get("/v1/jobs", params={"limit": 500}).json()["items"]]
    assert listed.count(first.json()["id"]) == 1


def test_list_filter_and_paging(http):
    ids = [submit(http, {"scenario": scenario(steps=2)})["id"] for _ in range(3)]
    for i in ids:
        wait_for(http, i)
    page1 = http.get("/v1/jobs", params={"limit": 2}).json()
    assert [j["id"] for j in page1["items"]] == ids[::-1][:2]
    page2 = http.get("/v1/jobs", params={"limit": 2, "cursor": page1["next_cursor"]}).json()
    assert page2["items"][0]["id"] == ids[0]
    done = http.get("/v1/jobs", params={"status": ["succeeded"], "limit": 500}).json()
    assert all(j["status"] == "succeeded" for j in done["items"])
    assert set(ids) <= {j["id"] for j in done["items"]}
    none = http.get("/v1/jobs", params={"model": "no-such-model"}).json()
    assert none == {"items": [], "next_cursor": None}


def test_server_sent_events_follow_progress_to_the_end(http):
    job = submit(http, {"scenario": scenario(n=1000, steps=300, every=0)})
    events, statuses = [], []
    with http.stream("GET", f"/v1/jobs/{job['id']}/events") as r:
        assert r.headers["content-type"].startswith("text/event-stream")
        name = None
        for line in r.iter_lines():
            if line.startswith("event: "):
                name = line[7:]
            elif line.startswith("data: "):
                events.append(name)
                if name == "job":
                    statuses.append(json.loads(line[6:]))
    assert events[-1] == "end"
    assert statuses[-1]["status"] == "succeeded" and statuses[-1]["progress"] == 1.0
    progress = [s["progress"] for s in statuses]
    assert progress == sorted(progress) and len(statuses) >= 2


def test_long_poll_returns_on_change(http):
    job = submit(http, {"scenario": scenario(steps=5)})
    t0 = time.monotonic()
    while job["status"] not in ("succeeded", "failed"):
        job = http.get(f"/v1/jobs/{job['id']}", params={"wait": 20}).json()
    assert time.monotonic() - t0 < 15  # answered on the change, not after 20 s each time


def test_healthz_stays_fast_while_a_job_runs(http):
    job = submit(http, {"scenario": long_scenario()})
    try:
        wait_for(http, job["id"], {"running"})
        worst = 0.0
        for _ in range(10):
            t0 = time.perf_counter()
            assert http.get("/healthz").json()["running"] == 1
            worst = max(worst, time.perf_counter() - t0)
        assert worst < 0.2
    finally:
        http.post(f"/v1/jobs/{job['id']}/cancel")
        wait_for(http, job["id"])


def test_catalog(http):
    models = http.get("/v1/models").json()
    kinds = [m["kind"] for m in models]
    assert "vicsek" in kinds and all("json_schema" in m for m in models)
    schema = http.get("/v1/models/vicsek").json()
    assert "eta" in schema["properties"]
    assert_problem(http.get("/v1/models/no-such-model"), 404)
    presets = {p["name"]: p for p in http.get("/v1/presets").json()}
    assert presets["vicsek-1995"]["scenario"]["initial"]["N"] == 300


def test_openapi_documents_every_route_with_problem_errors(http):
    spec = http.get("/openapi.json").json()
    ops = {(m, p) for p, item in spec["paths"].items() for m in item}
    assert {("post", "/v1/jobs"), ("get", "/v1/jobs/{job_id}/trajectory"),
            ("get", "/v1/jobs/{job_id}/events"), ("get", "/healthz")} <= ops
    post = spec["paths"]["/v1/jobs"]["post"]
    assert post["requestBody"]["content"]["application/json"]["examples"]
    assert "application/problem+json" in post["responses"]["422"]["content"]
    assert "Scenario" in spec["components"]["schemas"]


def test_cors_is_off_by_default(http):
    r = http.get("/v1/models", headers={"Origin": "https://evil.example"})
    assert "access-control-allow-origin" not in r.headers
