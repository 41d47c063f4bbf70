"""A sweep whose runs checkpoint (docs/CHECKPOINTS.md, "Sweeps"): stopped or killed with
SIGKILL in the middle of a run, then run again into its folder, it goes on with that run
from the run's checkpoint, not from step 0, says so, and ends with the runs.csv, table.csv
and series.csv of the sweep never interrupted, byte for byte (keep = all: each run's
trajectory.h5 and observables.csv too). A damaged checkpoint is refused and its run
redone from step 0, to the same bytes. The same through a real server: its worker
killed, or the whole API killed and restarted, mid-run."""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import httpx
import pytest

from flocklab.schemas.sweep import Sweep
from flocklab.service.checkpoints import CHECKPOINT
from flocklab.service.sweeps.runner import run_sweep
from tests.kernels.test_checkpoint import assert_same_run
from tests.service.conftest import TEST_ENV
from tests.service.sweeps.test_sweeps import _worker_pids, submit, wait_sweep

TABLES = ("runs.csv", "table.csv", "series.csv")
EVERY = 200


def spec(n: int = 300, steps: int = 600, every: int = EVERY, keep: str = "summaries",
         etas: tuple[float, ...] = (0.5, 2.5), replicas: int = 1) -> dict[str, Any]:
    """A Vicsek η scan whose runs checkpoint every `every` steps (frames for keep = all)."""
    return {
        "name": "ckpt",
        "base": {
            "model": {"kind": "vicsek", "rule": "vicsek", "v0": 0.1},
            "space": {"kind": "periodic", "L": (n / 2) ** 0.5},
            "neighbours": {"radius": 1.0},
            "initial": {"kind": "random", "N": n},
            "time": {"steps": steps},
            "recording": {"every": 150 if keep == "all" else 0, "arrays": ["position"],
                          "observables_every": 10, "checkpoint_every": every},
            "seed": 5, "backend": "cpu",
        },
        "axes": [{"path": "model.eta", "values": list(etas)}],
        "replicas": replicas,
        "measure": {"va": {"observable": "polarization", "reduce": "mean", "from_step": 100}},
        "series": ["polarization"],
        "keep": keep,
    }


def reference(tmp: Path, data: dict[str, Any]) -> Path:
    """The sweep run in this process, never interrupted."""
    out = tmp / "reference"
    outcome = run_sweep(Sweep.model_validate(data), out)
    assert outcome.status == "completed" and not outcome.checkpoints_resumed
    return out


def assert_same_tables(ref: Path, got: Path, keep: str = "summaries") -> None:
    for name in TABLES:
        assert (ref / name).read_bytes() == (got / name).read_bytes(), name
    if keep == "all":
        for run in sorted((ref / "runs").iterdir()):
            assert_same_run(run, got / "runs" / run.name)
    assert not list(got.glob("runs/*/" + CHECKPOINT)), "a finished run kept its checkpoint"
    assert not list(got.glob("runs/.*.partial-*"))


def stopped_at_first_checkpoint(out: Path, data: dict[str, Any]) -> None:
    def stop() -> bool:
        return bool(list(out.glob("runs/*/" + CHECKPOINT)) or list(
            out.glob("runs/.*.partial-*/" + CHECKPOINT)))

    outcome = run_sweep(Sweep.model_validate(data), out, should_stop=stop)
    assert outcome.status == "cancelled" and outcome.runs_done == 0


@pytest.mark.parametrize("keep", ["table", "summaries", "all"])
def test_a_stopped_sweep_goes_on_from_its_runs_checkpoint(tmp_path, keep):
    data = spec(keep=keep)
    ref = reference(tmp_path, data)
    out = tmp_path / "sweep"
    stopped_at_first_checkpoint(out, data)
    told: list[tuple[int, int | None]] = []
    outcome = run_sweep(Sweep.model_validate(data), out,
                        on_resumed=lambda run, step: told.append((run, step)))
    assert outcome.status == "completed" and outcome.runs_done == 2
    assert told == [(0, EVERY)] and outcome.checkpoints_resumed == {0: EVERY}
    if keep == "table":  # nothing of the runs is kept but their rows
        assert not (out / "runs").exists()
        assert_same_tables(ref, out, keep)
        return
    summary = json.loads((out / "runs" / "0" / "summary.json").read_text())
    assert summary["resumed_from_step"] == EVERY and summary["steps"] == 600
    assert "resumed_from_step" not in json.loads(
        (out / "runs" / "1" / "summary.json").read_text())
    assert_same_tables(ref, out, keep)


def test_a_damaged_run_checkpoint_is_refused_and_the_run_redone(tmp_path):
    data = spec()
    ref = reference(tmp_path, data)
    out = tmp_path / "sweep"
    stopped_at_first_checkpoint(out, data)
    ck = out / "runs" / "0" / CHECKPOINT
    raw = bytearray(ck.read_bytes())
    raw[len(raw) // 2] ^= 0xFF
    ck.write_bytes(bytes(raw))
    told: list[tuple[int, int | None]] = []
    outcome = run_sweep(Sweep.model_validate(data), out,
                        on_resumed=lambda run, step: told.append((run, step)))
    assert told == [(0, None)] and outcome.checkpoints_resumed == {}
    assert outcome.status == "completed"
    assert "resumed_from_step" not in json.loads(
        (out / "runs" / "0" / "summary.json").read_text())
    assert_same_tables(ref, out)


def test_the_sweep_without_checkpoints_has_the_same_tables(tmp_path):
    """Checkpoints (each run alone, windows cut at every k-th step) change no bit: the
    tables equal those of the sweep whose runs fuse into one batch, uncheckpointed."""
    data = spec()
    ref = reference(tmp_path, data)
    plain = spec(every=0)
    out = tmp_path / "plain"
    run_sweep(Sweep.model_validate(plain), out)
    for name in TABLES:
        assert (ref / name).read_bytes() == (out / name).read_bytes(), name


# -- killed: the CLI and the service ---------------------------------------------------

# Two runs of N = 2000 for 3000 steps (about 10 s each on one thread), a checkpoint every
# 200 steps.
LONG = spec(n=2000, steps=3000, etas=(0.5, 2.5))
LONG_ALL = spec(n=2000, steps=3000, etas=(0.5, 2.5), keep="all")


def _checkpoints(root: Path) -> list[Path]:
    return [*root.glob("**/runs/*/" + CHECKPOINT), *root.glob("**/runs/.*/" + CHECKPOINT)]


def _wait_checkpoint(root: Path, rng: random.Random, proc: Any = None) -> None:
    """Until a run under `root` checkpointed, then a random moment more."""
    deadline = time.monotonic() + 120
    while not _checkpoints(root):
        assert time.monotonic() < deadline, "no run wrote a checkpoint"
        assert proc is None or proc.poll() is None, "the sweep ended first"
        time.sleep(0.05)
    time.sleep(rng.uniform(0.0, 1.0))


@pytest.mark.slow
def test_flocklab_sweep_killed_mid_run_resumes_from_its_checkpoint(tmp_path):
    ref = reference(tmp_path, LONG)
    path = tmp_path / "sweep.json"
    path.write_text(json.dumps(LONG))
    out = tmp_path / "killed"
    cmd = [sys.executable, "-m", "flocklab", "sweep", str(path), "--out", str(out)]
    rng = random.Random(4)
    for _ in range(2):  # killed in the middle of a run, twice
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        before = {p: p.stat().st_mtime_ns for p in _checkpoints(out)}
        deadline = time.monotonic() + 120
        while not any(p.stat().st_mtime_ns != before.get(p) for p in _checkpoints(out)):
            assert proc.poll() is None and time.monotonic() < deadline
            time.sleep(0.05)
        time.sleep(rng.uniform(0.0, 0.8))
        proc.send_signal(signal.SIGKILL)
        proc.communicate()
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    line = json.loads(done.stdout)
    resumed = line["checkpoints_resumed"]
    assert line["status"] == "completed" and len(resumed) == 1, line
    ((run, step),) = resumed.items()
    assert 0 < step < 3000 and step % EVERY == 0
    assert f"run {run} goes on from its checkpoint at step {step}" in done.stderr
    assert_same_tables(ref, out)


SERVICE_ENV = {**TEST_ENV, "FLOCKLAB_MAX_SWEEP_AGENT_STEPS": "20000000"}


def _events(http: httpx.Client, sweep_id: str) -> list[dict]:
    """The sweep's Server-Sent Events (`data:` rows) until its `event: end`."""
    rows, name = [], None
    with http.stream("GET", f"/v1/sweeps/{sweep_id}/events", timeout=180) as r:
        for line in r.iter_lines():
            if line.startswith("event: "):
                name = line.removeprefix("event: ")
                if name == "end":
                    break
            elif line.startswith("data: ") and name != "end":
                rows.append(json.loads(line.removeprefix("data: ")))
    return rows


def _assert_service_sweep(http: httpx.Client, done: dict, ref: Path, data: Path,
                          attempts: int = 2, keep: str = "summaries") -> dict[str, int]:
    assert done["status"] == "succeeded" and done["attempts"] == attempts, done
    assert done["runs_done"] == 2 and done["error"] is None
    resumed = done["resumed_runs"]
    assert resumed is not None and len(resumed) == 1, done
    ((run, step),) = resumed.items()
    assert 0 < step < 3000 and step % EVERY == 0
    for name in ("runs", "table", "series"):
        r = http.get(f"/v1/sweeps/{done['id']}/{name}", params={"format": "csv"})
        assert r.content == (ref / f"{name}.csv").read_bytes(), name
    folder = data / "results" / done["id"]
    summary = json.loads((folder / "runs" / run / "summary.json").read_text())
    assert summary["resumed_from_step"] == step
    assert_same_tables(ref, folder, keep)
    assert list((data / "results" / ".attempts").iterdir()) == []
    return resumed


@pytest.mark.slow
@pytest.mark.parametrize("keep", ["summaries", "all"])
def test_a_service_sweep_whose_worker_is_killed_resumes_its_run_from_its_checkpoint(
        make_server, tmp_path, keep):
    sweep = LONG_ALL if keep == "all" else LONG
    ref = reference(tmp_path, sweep)
    data = tmp_path / "data"
    server = make_server(env=SERVICE_ENV, data_dir=data)
    with httpx.Client(base_url=server.url, timeout=30) as http:
        created = submit(http, sweep)
        _wait_checkpoint(data / "results" / ".attempts", random.Random(2))
        running = http.get(f"/v1/sweeps/{created['id']}").json()
        assert running["status"] == "running" and running["resumed_runs"] is None
        (worker,) = _worker_pids(server)
        os.kill(worker, signal.SIGKILL)
        events = _events(http, created["id"])
        done = wait_sweep(http, created["id"], timeout=180)
        resumed = _assert_service_sweep(http, done, ref, data, keep=keep)
    # The events show the second attempt continuing the run from its checkpoint, before
    # that run ended.
    told = [e for e in events if e["resumed_runs"]]
    assert told and told[0]["attempts"] == 2 and told[0]["resumed_runs"] == resumed
    assert told[0]["runs_done"] < 2


@pytest.mark.slow
@pytest.mark.parametrize("graceful", [False, True], ids=["kill-9", "sigterm"])
def test_a_service_sweep_of_a_stopped_api_resumes_its_run_after_restart(
        make_server, tmp_path, graceful):
    ref = reference(tmp_path, LONG)
    data = tmp_path / "data"
    s1 = make_server(env=SERVICE_ENV, data_dir=data)
    with httpx.Client(base_url=s1.url, timeout=30) as http:
        created = submit(http, LONG)
        _wait_checkpoint(data / "results" / ".attempts", random.Random(3))
    if graceful:
        s1.stop()  # SIGTERM: the sweep is re-queued, its attempt not counted
    else:
        s1.kill()  # kill -9 the API; its orphaned worker stops at its next window
    s2 = make_server(env=SERVICE_ENV, data_dir=data)
    with httpx.Client(base_url=s2.url, timeout=30) as http:
        done = wait_sweep(http, created["id"], timeout=240)
        _assert_service_sweep(http, done, ref, data, attempts=1 if graceful else 2)
