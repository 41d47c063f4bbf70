"""A checkpointed job on a real server (docs/CHECKPOINTS.md, "In the service"): its worker
killed with SIGKILL, or the whole API killed and restarted on the same data directory,
the job goes on from its last checkpoint, not from step 0, says so in its events
(`resumed_from_step`), and ends with the artifacts of the same scenario run uninterrupted
by `flocklab run`, bit for bit (every dataset of trajectory.h5, observables.csv, the
summary but for its timings). A checkpoint damaged meanwhile is refused: the job runs
again from step 0, with a note, to the same bits."""

from __future__ import annotations

import json
import os
import random
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest

from tests.kernels.test_checkpoint import assert_same_run
from tests.service.jobs.test_durability import _alive, _workers
from tests.service.svc_helpers import submit, wait_for

CHECKPOINT_EVERY = 200
STEPS = 3000
# N = 2000 Vicsek agents for 3000 steps: about 10 s on one thread, a checkpoint every 200
# steps and a frame every 250 (13 frames), an observation every 10.
SCENARIO = {
    "model": {"kind": "vicsek", "rule": "vicsek", "v0": 0.1, "eta": 1.0},
    "space": {"kind": "periodic", "L": 2000 ** 0.5},
    "neighbours": {"radius": 1.0}, "initial": {"kind": "random", "N": 2000},
    "time": {"steps": STEPS, "dt": 1.0},
    "recording": {"every": 250, "arrays": ["position", "heading"], "observables_every": 10,
                  "checkpoint_every": CHECKPOINT_EVERY},
    "seed": 11, "backend": "cpu",
}


def _checkpoints(data: Path, job_id: str) -> list[Path]:
    """The job's checkpoints under the results root's attempt folders (hidden or not)."""
    attempts = data / "results" / ".attempts"
    return [*attempts.glob(f".{job_id}.*/checkpoint.npz"),
            *attempts.glob(f"{job_id}.*/checkpoint.npz")]


def _wait_checkpoint(data: Path, job_id: str, rng: random.Random) -> None:
    """Until the running job has written a checkpoint, then a random moment more."""
    deadline = time.monotonic() + 120
    while not _checkpoints(data, job_id):
        assert time.monotonic() < deadline, "the job wrote no checkpoint"
        time.sleep(0.05)
    time.sleep(rng.uniform(0.0, 1.0))


def _reference(tmp: Path, job_dir: Path) -> Path:
    """The job's own scenario.json run uninterrupted by `flocklab run`."""
    out = tmp / "reference"
    done = subprocess.run([sys.executable, "-m", "flocklab", "run",
                           str(job_dir / "scenario.json"), "--out", str(out), "--quiet"],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "resumed_from_step" not in json.loads(done.stdout)
    return out


def _events(http: httpx.Client, job_id: str) -> list[dict]:
    """The job's Server-Sent Events (`event: job` rows) until its `event: end`."""
    rows, name = [], None
    with http.stream("GET", f"/v1/jobs/{job_id}/events", timeout=180) as r:
        for line in r.iter_lines():
            if line.startswith("event: "):
                name = line.removeprefix("event: ")
                if name == "end":
                    break
            elif line.startswith("data: ") and name != "end":
                rows.append(json.loads(line.removeprefix("data: ")))
    return rows


def _assert_resumed(job: dict, data: Path, tmp: Path, attempts: int = 2) -> int:
    step = job["resumed_from_step"]
    assert job["status"] == "succeeded" and job["attempts"] == attempts, job
    assert step is not None and 0 < step < STEPS and step % CHECKPOINT_EVERY == 0, job
    job_dir = data / "results" / job["id"]
    summary = json.loads((job_dir / "summary.json").read_text())
    assert summary["resumed_from_step"] == step and summary["steps"] == STEPS
    assert_same_run(_reference(tmp, job_dir), job_dir)
    assert list((data / "results" / ".attempts").iterdir()) == []
    return step


@pytest.mark.slow
def test_a_job_whose_worker_is_killed_resumes_from_its_checkpoint_bit_identical(
        make_server, tmp_path):
    data = tmp_path / "data"
    server = make_server(data_dir=data)
    with httpx.Client(base_url=server.url, timeout=30) as http:
        job = submit(http, {"scenario": SCENARIO})
        _wait_checkpoint(data, job["id"], random.Random(1))
        running = http.get(f"/v1/jobs/{job['id']}").json()
        assert running["status"] == "running" and running["resumed_from_step"] is None
        (worker,) = _workers(server)
        os.kill(worker, signal.SIGKILL)
        events = _events(http, job["id"])
        done = wait_for(http, job["id"], timeout=180)
    assert done["error"] is None
    step = _assert_resumed(done, data, tmp_path)
    # The events show the second attempt resuming at the checkpoint's step, and its
    # progress going on from there (never back through the steps before it).
    resumed = [e for e in events if e["resumed_from_step"] is not None]
    assert resumed and resumed[0]["attempts"] == 2 and resumed[0]["steps_done"] >= step
    assert all(e["resumed_from_step"] == step for e in resumed)
    assert [e["steps_done"] for e in resumed] == sorted(e["steps_done"] for e in resumed)


def _kill_service_mid_job(make_server, data: Path, seed: int, graceful: bool = False) -> str:
    """Submit the job, SIGKILL the API once it checkpointed (`graceful`: SIGTERM), wait
    for its worker to stop (an orphan lands its run stopped, checkpoint kept); the
    job's id."""
    s1 = make_server(data_dir=data)
    with httpx.Client(base_url=s1.url, timeout=30) as http:
        job = submit(http, {"scenario": SCENARIO})
        _wait_checkpoint(data, job["id"], random.Random(seed))
        workers = _workers(s1)
    if graceful:
        s1.stop()
    else:
        s1.kill()
    deadline = time.monotonic() + 30
    while any(_alive(p) for p in workers) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not any(_alive(p) for p in workers)
    assert _checkpoints(data, job["id"])
    return job["id"]


def _finish_on_a_new_service(make_server, data: Path, job_id: str) -> dict:
    s2 = make_server(data_dir=data)
    with httpx.Client(base_url=s2.url, timeout=30) as http:
        return wait_for(http, job_id, timeout=180)


@pytest.mark.slow
@pytest.mark.parametrize("graceful", [False, True], ids=["kill-9", "sigterm"])
def test_a_job_of_a_stopped_service_resumes_after_restart_bit_identical(
        make_server, tmp_path, graceful):
    data = tmp_path / "data"
    job_id = _kill_service_mid_job(make_server, data, seed=2, graceful=graceful)
    done = _finish_on_a_new_service(make_server, data, job_id)
    # A graceful stop re-queues the job without counting its attempt.
    assert done["error"] is None
    _assert_resumed(done, data, tmp_path, attempts=1 if graceful else 2)


@pytest.mark.slow
def test_a_corrupted_checkpoint_is_not_resumed_the_job_runs_again_from_step_0(
        make_server, tmp_path):
    data = tmp_path / "data"
    job_id = _kill_service_mid_job(make_server, data, seed=3)
    (ck,) = _checkpoints(data, job_id)
    raw = bytearray(ck.read_bytes())
    raw[len(raw) // 2] ^= 0xFF  # one flipped byte inside the arrays
    ck.write_bytes(bytes(raw))
    done = _finish_on_a_new_service(make_server, data, job_id)
    assert done["status"] == "succeeded" and done["attempts"] == 2, done
    assert done["resumed_from_step"] is None
    job_dir = data / "results" / job_id
    summary = json.loads((job_dir / "summary.json").read_text())
    assert "resumed_from_step" not in summary
    (note,) = summary.pop("notes")
    assert "checkpoint was refused" in note and "corrupted" in note and "step 0" in note
    assert str(data) not in note  # clients never see the data directory's paths
    # The run from step 0 has the reference's bits; its summary but for the note, too.
    summary.pop("backend_requested")
    got = tmp_path / "got"
    shutil.copytree(job_dir, got)
    (got / "summary.json").write_text(json.dumps(summary))
    assert_same_run(_reference(tmp_path, job_dir), got)
    assert list((data / "results" / ".attempts").iterdir()) == []
