"""Service benchmark: what the job service adds on top of the engine.

    python bench/service_bench.py [--runs 20] [--large-n 100000] [--large-steps 100]

Prints one JSON line per measurement:
  small_job   a warm N=1000, 100-step job, submit -> succeeded -> metrics fetched, over
              `--runs` runs (median, p90), next to the engine's own wall time per job;
  large_job   at N=--large-n: submit -> metrics through the service, against the bare
              engine (`kernels.run`, and `execute_to_dir` which also writes the
              artifacts) in this process, each the median of `--large-runs` warm runs,
              service and bare runs alternating.
The server is a real `flocklab serve` on 127.0.0.1 with one worker; nothing runs
concurrently with a measurement.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from flocklab import clients
from flocklab.schemas import Scenario
from flocklab.service.serve import ServerProcess


def vicsek(n: int, steps: int) -> dict[str, Any]:
    """Vicsek at density 4 with r = 1: frames and observables every 10 steps."""
    return {
        "model": {"kind": "vicsek", "rule": "vicsek", "v0": 0.03, "eta": 0.5,
                  "track_linked_intervals": False},
        "space": {"kind": "periodic", "L": (n / 4.0) ** 0.5},
        "neighbours": {"radius": 1.0},
        "initial": {"kind": "random", "N": n},
        "time": {"steps": steps},
        "recording": {"every": 10, "arrays": ["position", "heading"], "observables_every": 10},
        "seed": 1,
    }


def emit(**fields: Any) -> None:
    print(json.dumps(fields), flush=True)


def timed_job(c: clients.Client, spec: dict[str, Any]) -> tuple[float, float]:
    """(submit -> metrics wall time, the engine's wall time inside the job)."""
    t0 = time.perf_counter()
    job = c.submit(spec).wait(timeout=3600, progress=False)
    m = job.metrics()
    total = time.perf_counter() - t0
    assert job.status == "succeeded", job.data
    return total, m["summary"]["wall_seconds"]


def bare(scenario: Scenario) -> tuple[float, float]:
    """Wall time of kernels.run and of execute_to_dir for one run, in this process."""
    from flocklab import kernels
    from flocklab.service.execute import execute_to_dir

    t0 = time.perf_counter()
    kernels.run(scenario)
    run_s = time.perf_counter() - t0
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        execute_to_dir(scenario, Path(tmp) / "out")
        return run_s, time.perf_counter() - t0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--large-n", type=int, default=100_000)
    ap.add_argument("--large-steps", type=int, default=100)
    ap.add_argument("--large-runs", type=int, default=3)
    args = ap.parse_args()

    small = vicsek(1000, 100)
    large = vicsek(args.large_n, args.large_steps)
    with tempfile.TemporaryDirectory() as tmp:
        server = ServerProcess(Path(tmp) / "data", env={
            "FLOCKLAB_WORKERS": "1", "FLOCKLAB_MAX_AGENTS": str(max(args.large_n, 1000)),
            "TI_LOG_LEVEL": "error"}, log_level="warning")
        server.start(timeout=120)
        try:
            with clients.Client(server.url) as c:
                for _ in range(3):  # warm: worker started, kernels compiled
                    timed_job(c, small)
                pairs = [timed_job(c, small) for _ in range(args.runs)]
                totals = [t for t, _ in pairs]
                emit(bench="small_job", n_agents=1000, steps=100, runs=args.runs,
                     median_s=round(statistics.median(totals), 4),
                     p90_s=round(statistics.quantiles(totals, n=10)[-1], 4),
                     engine_median_s=round(statistics.median(e for _, e in pairs), 4),
                     overhead_median_s=round(statistics.median(t - e for t, e in pairs), 4))
                # Service and bare runs alternate (the worker idles meanwhile), so a
                # change in the machine's load hits both alike.
                scenario = Scenario.model_validate_json(json.dumps(large))
                timed_job(c, large)  # warm at this N, in the worker and here
                bare(scenario)
                service, run_s, exec_s = [], [], []
                for _ in range(args.large_runs):
                    service.append(timed_job(c, large)[0])
                    r, e = bare(scenario)
                    run_s.append(r)
                    exec_s.append(e)
        finally:
            server.stop()
    svc, run, ex = (statistics.median(x) for x in (service, run_s, exec_s))
    emit(bench="large_job", n_agents=args.large_n, steps=args.large_steps,
         runs=args.large_runs, service_median_s=round(svc, 3),
         bare_kernels_run_median_s=round(run, 3), bare_execute_to_dir_median_s=round(ex, 3),
         overhead_vs_kernels_run_pct=round(100 * (svc / run - 1), 1),
         overhead_vs_execute_to_dir_pct=round(100 * (svc / ex - 1), 1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
