"""Issue 12, finding 9: damaged or deleted results say what happened; bad Range headers are
problem+json; SIGTERM releases long-polls and streams at once; a second service on a
locked data directory exits 1."""

from __future__ import annotations

import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

import httpx
import pytest

from flocklab.service.serve import free_port
from tests.service.jobs.test_durability import _wait_running
from tests.service.svc_helpers import assert_problem, long_scenario, scenario, submit, wait_for


@pytest.fixture
def finished(server, http) -> tuple[str, Path]:
    """A fresh succeeded job of the shared server and its results folder."""
    job = wait_for(http, submit(http, {"scenario": scenario()})["id"])
    assert job["status"] == "succeeded"
    return job["id"], Path(server.data_dir) / "results" / job["id"]


@pytest.mark.parametrize(("name", "route"), [
    ("summary.json", "metrics"),
    ("observables.csv", "metrics"),
    ("trajectory.h5", "trajectory"),
    ("trajectory.h5", "trajectory?format=json"),
])
def test_a_damaged_result_file_is_results_corrupted(http, finished, name, route):
    job_id, folder = finished
    if name == "observables.csv":
        (folder / name).unlink()
    else:
        (folder / name).write_bytes(b"\xff\xfe garbage, not the file it was")
    body = assert_problem(http.get(f"/v1/jobs/{job_id}/{route}"), 500)
    assert body["type"].endswith("results-corrupted") and body["file"] == name
    assert str(folder) not in body["detail"] and "/" not in body["detail"]


def test_a_deleted_results_folder_is_results_missing_not_expired(http, finished):
    job_id, folder = finished
    shutil.rmtree(folder)
    for route in ("metrics", "trajectory", "trajectory.h5"):
        body = assert_problem(http.get(f"/v1/jobs/{job_id}/{route}"), 410)
        assert body["type"].endswith("results-missing"), body


def test_range_requests(http, finished):
    job_id, folder = finished
    url = f"/v1/jobs/{job_id}/trajectory.h5"
    size = (folder / "trajectory.h5").stat().st_size
    ok = http.get(url, headers={"Range": "bytes=0-99"})
    assert ok.status_code == 206 and len(ok.content) == 100
    for bad in ("bytes=abc", "items=0-1", "bytes=5-1"):
        body = assert_problem(http.get(url, headers={"Range": bad}), 400)
        assert body["type"].endswith("bad-range")
    r = http.get(url, headers={"Range": f"bytes={size + 10}-"})
    body = assert_problem(r, 416)
    assert r.headers["Content-Range"] == f"bytes */{size}"


@pytest.mark.slow
def test_sigterm_answers_long_polls_and_ends_streams_at_once(make_server):
    s = make_server()
    with httpx.Client(base_url=s.url, timeout=60) as http:
        running = submit(http, {"scenario": long_scenario()})
        _wait_running(http, running["id"])
        waiting = submit(http, {"scenario": scenario()})  # queued behind it: no changes
        answers: dict[str, object] = {}

        def long_poll() -> None:
            with httpx.Client(base_url=s.url, timeout=60) as c:
                r = c.get(f"/v1/jobs/{waiting['id']}", params={"wait": 60})
                answers["poll"] = (r.status_code, r.json().get("status"))

        def stream() -> None:
            with httpx.Client(base_url=s.url, timeout=60) as c, \
                    c.stream("GET", f"/v1/jobs/{waiting['id']}/events") as r:
                answers["events"] = [line for line in r.iter_lines() if line.startswith("event")]

        threads = [threading.Thread(target=long_poll), threading.Thread(target=stream)]
        for t in threads:
            t.start()
        time.sleep(1.0)
        assert http.get(f"/v1/jobs/{waiting['id']}").json()["status"] == "queued"
    started = time.monotonic()
    s.stop()
    stopped = time.monotonic() - started
    for t in threads:
        t.join(30)
    assert answers["poll"] == (200, "queued"), answers
    assert answers["events"][-1] == "event: shutdown", answers
    # Not the 10 s grace period for open connections, then a cancelled (500) long-poll.
    assert stopped < 8, stopped
    assert "Cancel" not in s.log_path.read_text()


def test_a_second_service_on_a_locked_data_dir_exits_1(make_app, tmp_path):
    data = tmp_path / "data"
    make_app(data_dir=data)  # the first service holds the lock (in this process)
    second = subprocess.run(
        [sys.executable, "-m", "flocklab.service.serve", "--data-dir", str(data),
         "--port", str(free_port())], capture_output=True, text=True, timeout=120,
        env={"FLOCKLAB_WARMUP_PRESET": "", "PATH": "/usr/bin:/bin"})
    assert second.returncode == 1, second.stderr[-2000:]
    assert "another flocklab service" in second.stderr
