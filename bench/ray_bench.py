"""Ray executor benchmark (the scale-out issue's bar): one JSON line per measurement.

    python -m bench.ray_bench              # both measurements
    python -m bench.ray_bench --overhead   # the 200-run overhead sweep only (cold, warm)
    python -m bench.ray_bench --warm       # its warm (long-lived driver) pass only
    python -m bench.ray_bench --fig2a      # the reduced Fig. 2a table check only

It starts its own two-node Ray cluster on 127.0.0.1 (1 CPU per node, bench/local_ray.py),
stops it at the end, and runs every sweep through `flocklab sweep` in a fresh process
(start-up, Ray connection and Taichi initialisation included), local executor vs
`--executor ray`, each twice: the first run warms the Taichi offline cache (and, for Ray,
the worker processes), the second is the one reported.

- overhead: 200 small runs (Vicsek, N = 100, density 4, 1000 steps, 10 values of eta x 20
  replicas, polarization final); reports both wall times, their ratio (bar: ray <= 1.5x
  local), the Ray tasks' count and the overhead per task in ms = (ray - local) / tasks.
- overhead-warm: the same, each executor twice in one process (a long-lived driver, as
  the service's workers are); the second pass is reported.
- fig2a: examples/sweep-fig2a-reduced.json; reports whether table.csv is byte-equal.
Load averages are printed with each line: the machine is shared.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bench.local_ray import RAY_ENV, LocalRayCluster  # noqa: E402

OVERHEAD_SWEEP = {
    "name": "ray-overhead",
    "base": {
        "model": {"kind": "vicsek", "rule": "vicsek", "v0": 0.03,
                  "position_update": "new_heading", "track_linked_intervals": False},
        "space": {"kind": "periodic", "L": 5.0},
        "neighbours": {"radius": 1.0, "inclusive": True},
        "initial": {"kind": "random", "N": 100},
        "time": {"steps": 1000},
        "recording": {"every": 0, "observables_every": 100},
        "seed": 1,
    },
    "axes": [{"path": "model.eta", "values": [round(0.5 * k, 1) for k in range(1, 11)]}],
    "replicas": 20,
    "measure": {"va": {"observable": "polarization", "reduce": "final"}},
    "keep": "table",
}


def load() -> list[float]:
    return [round(x, 2) for x in os.getloadavg()]


def sweep(spec: Path, out: Path, address: str | None) -> float:
    """Wall seconds of one `flocklab sweep` into a fresh folder (as the CLI reports it)."""
    cmd = [sys.executable, "-m", "flocklab", "sweep", str(spec), "--out", str(out),
           "--quiet"]
    if address:
        cmd += ["--executor", "ray", "--ray-address", address]
    res = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, timeout=1800)
    if res.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{res.stderr}")
    return float(json.loads(res.stdout.splitlines()[-1])["wall_seconds"])


def best_of_two(spec: Path, tmp: Path, name: str, address: str | None) -> tuple[float, Path]:
    times = []
    for k in range(2):
        out = tmp / f"{name}-{k}"
        times.append(sweep(spec, out, address))
    return times[-1], out


def overhead(cluster: LocalRayCluster, tmp: Path) -> None:
    spec = tmp / "overhead.json"
    spec.write_text(json.dumps(OVERHEAD_SWEEP))
    local, local_out = best_of_two(spec, tmp, "overhead-local", None)
    ray, ray_out = best_of_two(spec, tmp, "overhead-ray", cluster.address)
    runs = 200
    # The executor's chunking (ray_executor.RayExecutor.chunk_size) on this 2-CPU cluster.
    tasks = math.ceil(runs / max(1, min(64, math.ceil(runs / (4 * 2)))))
    same = (ray_out / "table.csv").read_bytes() == (local_out / "table.csv").read_bytes()
    print(json.dumps({
        "bench": "ray-overhead", "runs": runs, "N": 100, "steps": 1000,
        "local_seconds": local, "ray_seconds": ray, "ratio": round(ray / local, 3),
        "bar_ratio": 1.5, "ray_tasks": tasks,
        "overhead_ms_per_task": round(1000 * (ray - local) / tasks, 1),
        "per_run_ms_local": round(1000 * local / runs, 2),
        "per_run_ms_ray": round(1000 * ray / runs, 2),
        "tables_equal": same, "loadavg": load()}), flush=True)


def overhead_warm(cluster: LocalRayCluster, tmp: Path) -> None:
    """The same 200 runs, each executor twice in one long-lived process (as a service
    worker drives them): the second pass has Taichi initialised and, for Ray, its worker
    processes started (Ray keeps a driver's workers, not another driver's)."""
    code = f"""
import json, sys, time
from pathlib import Path
from flocklab.schemas.sweep import load_sweep
from flocklab.service.sweeps.executors import ExecutorConfig
from flocklab.service.sweeps.factory import make_executor
from flocklab.service.sweeps.runner import run_sweep
sweep = load_sweep(json.loads(Path(sys.argv[1]).read_text()))
ex = make_executor(ExecutorConfig(kind=sys.argv[2], ray_address={cluster.address!r}))
times = []
for k in range(2):
    t0 = time.perf_counter()
    run_sweep(sweep, Path(sys.argv[3]) / str(k), executor=ex)
    times.append(time.perf_counter() - t0)
print(json.dumps(times))
"""
    spec = tmp / "overhead.json"
    spec.write_text(json.dumps(OVERHEAD_SWEEP))
    got = {}
    for kind in ("local", "ray"):
        res = subprocess.run([sys.executable, "-c", code, str(spec), kind,
                              str(tmp / f"warm-{kind}")], capture_output=True, text=True,
                             cwd=ROOT, timeout=1800)
        if res.returncode != 0:
            raise RuntimeError(res.stderr)
        got[kind] = json.loads(res.stdout.splitlines()[-1])
    local, ray = got["local"][1], got["ray"][1]
    tasks = 8
    print(json.dumps({
        "bench": "ray-overhead-warm", "runs": 200, "local_seconds": round(local, 3),
        "ray_seconds": round(ray, 3), "ratio": round(ray / local, 3),
        "first_pass": {k: round(v[0], 3) for k, v in got.items()}, "ray_tasks": tasks,
        "overhead_ms_per_task": round(1000 * (ray - local) / tasks, 1),
        "loadavg": load()}), flush=True)


def fig2a(cluster: LocalRayCluster, tmp: Path) -> None:
    spec = ROOT / "examples" / "sweep-fig2a-reduced.json"
    local = sweep(spec, tmp / "fig2a-local", None)
    ray = sweep(spec, tmp / "fig2a-ray", cluster.address)
    same = ((tmp / "fig2a-ray" / "table.csv").read_bytes()
            == (tmp / "fig2a-local" / "table.csv").read_bytes())
    print(json.dumps({"bench": "ray-fig2a-reduced", "runs": 80, "local_seconds": local,
                      "ray_seconds": ray, "table_csv_byte_equal": same,
                      "loadavg": load()}), flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--overhead", action="store_true")
    ap.add_argument("--warm", action="store_true", help="the warm overhead pass only")
    ap.add_argument("--fig2a", action="store_true")
    args = ap.parse_args()
    both = not (args.overhead or args.fig2a or args.warm)
    os.environ.update(RAY_ENV)
    t0 = time.perf_counter()
    cluster = LocalRayCluster(cpus_head=1, cpus_node=1).start()
    print(json.dumps({"bench": "ray-cluster-start", "seconds": round(time.perf_counter() - t0, 1),
                      "address": cluster.address, "loadavg": load()}), flush=True)
    try:
        with tempfile.TemporaryDirectory(prefix="flocklab-ray-bench-") as tmp:
            if both or args.overhead:
                overhead(cluster, Path(tmp))
            if both or args.overhead or args.warm:
                overhead_warm(cluster, Path(tmp))
            if both or args.fig2a:
                fig2a(cluster, Path(tmp))
    finally:
        cluster.stop()


if __name__ == "__main__":
    main()
