"""A sweep's runs expanded lazily and its finished runs' records left in the journal
(issue 28): the runner expanded every run at once (`Sweep.expand`, a validated scenario
each) and kept every finished run's record, so the worker of a 10^5-run sweep held
hundreds of MiB growing with every run."""

from __future__ import annotations

import gc
import json
from pathlib import Path

import httpx
import pytest

from flocklab.schemas.sweep import SweepRun, load_sweep
from flocklab.service.sweeps import SweepProgress, run_sweep
from flocklab.service.sweeps.executors import BATCH_RUNS
from flocklab.service.sweeps.tables import SWEEP_FILE
from tests.service.sweeps.test_sweeps import _worker_pids, submit, sweep_spec, wait_sweep

RECORD_KEYS = {"run", "status", "seed", "measures", "series", "error"}


def _alive() -> tuple[int, int]:
    """(SweepRun objects, journal records) alive in this process."""
    objs = gc.get_objects()
    return (sum(1 for o in objs if type(o) is SweepRun),
            sum(1 for o in objs if type(o) is dict and o.keys() == RECORD_KEYS))


@pytest.mark.slow
def test_the_runner_holds_neither_every_run_nor_every_record(tmp_path: Path, taichi_cpu):
    """300 runs: while they run, at most one engine batch of runs is alive (main: all
    300, from expand()) and no finished run's record beyond the one being written (main:
    every finished one); the tables still count every run, and sweep.json is the one
    `json.dumps(indent=2)` writes though it was written run by run."""
    spec = sweep_spec(etas=tuple(0.5 * i for i in range(10)), replicas=30, n=8, steps=4,
                      name="lazy")
    spec["base"]["recording"]["observables_every"] = 2
    spec["measure"]["va"]["from_step"] = 2
    sweep = load_sweep(spec)
    seen: list[tuple[int, int]] = []

    def on_progress(p: SweepProgress) -> None:
        if (p.runs_done + p.runs_failed) % 25 == 24:
            seen.append(_alive())

    outcome = run_sweep(sweep, tmp_path / "s", on_progress=on_progress)
    assert (outcome.status, outcome.runs_done) == ("completed", 300)
    assert len(seen) == 12
    assert max(runs for runs, _ in seen) <= BATCH_RUNS + 1, seen  # + the probed first run
    assert max(records for _, records in seen) <= 1, seen
    lines = (tmp_path / "s" / "runs.csv").read_text().splitlines()
    assert len(lines) == 301 and all(",completed," in line for line in lines[1:])
    raw = (tmp_path / "s" / SWEEP_FILE).read_text()
    doc = json.loads(raw)
    assert raw == json.dumps(doc, indent=2)
    assert [r["run"] for r in doc["runs"]] == list(range(300))
    assert [r["seed"] for r in doc["runs"][:31]] == [11 + k for k in range(30)] + [11]


def _peak_rss_mib(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    raise AssertionError("no VmHWM")


@pytest.mark.slow
def test_a_max_size_sweep_keeps_the_workers_memory_flat(make_server):
    """A real server runs a 10^5-run sweep (1000 grid points x 100 replicas) for 3000
    runs: the worker's peak RSS grows by less than 60 MiB over what a small sweep of the
    same model left it at (main: expand() alone held every run's scenario before the
    first run; bench/sweep_attack.py has the figures)."""
    s = make_server({"FLOCKLAB_MAX_SWEEP_RUNS": "100000",
                     "FLOCKLAB_MAX_SWEEP_AGENT_STEPS": str(10**12),
                     "FLOCKLAB_MAX_BODY_BYTES": str(4 * 2**20),
                     "FLOCKLAB_MAX_JSON_BYTES": str(4 * 2**20),
                     "FLOCKLAB_THREADS_PER_WORKER": "1"})
    spec = sweep_spec(etas=tuple(round(5 * i / 1000, 6) for i in range(1000)),
                      replicas=100, n=16, steps=20, name="max-size")
    with httpx.Client(base_url=s.url, timeout=120) as http:
        warm = submit(http, {**spec, "axes": [{"path": "model.eta", "values": [0.5, 1.0]}],
                             "name": "warm-up"})
        assert wait_sweep(http, warm["id"])["status"] == "succeeded"
        [worker] = _worker_pids(s)
        before = _peak_rss_mib(worker)
        created = submit(http, spec)
        assert created["runs_total"] == 100_000
        wait_sweep(http, created["id"], until=lambda v: v["runs_done"] >= 3000, timeout=300)
        assert _worker_pids(s) == [worker]
        peak = _peak_rss_mib(worker)
        http.post(f"/v1/sweeps/{created['id']}/cancel")
        done = wait_sweep(http, created["id"], timeout=120)
    assert done["status"] == "cancelled" and done["runs_done"] >= 3000
    assert peak - before < 60, (before, peak)
