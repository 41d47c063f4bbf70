"""Per-step cost of each schedule for a set of replicas: one JSON line per cell.

    python -m bench.schedules                       # N = 100, 1000, 10^4 x 1, 16, 64 replicas
    python -m bench.schedules --sizes 100 --replicas 1 64
    python -m bench.schedules --backend cuda --paths per_step batched   # a GPU

The workload: Vicsek rule, density 4 (r = 1, L = sqrt(N / 4)), eta = 2, every observable
every 10 steps (the defaults a user gets), seeds 1 .. B, through `kernels.run_batch(...,
path=...)` on every core, as a sweep hands the engine its runs. Each cell is timed after a
warm-up run of the same schedule (compile excluded); `wall_us_per_step` is the whole set's
wall time per step, `ns_per_agent_step` that over B * N. `auto` is the schedule
`kernels.run_batch(..., path="auto")` takes for the set.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time

SCHEDULES = ("per_step", "fused", "batched")


BACKEND = "cpu"


def scenario(n: int, seed: int, steps: int):
    from flocklab.schemas import Scenario

    return Scenario.model_validate({
        "backend": BACKEND,
        "model": {"kind": "vicsek", "rule": "vicsek", "v0": 0.03, "eta": 2.0},
        "space": {"kind": "periodic", "L": max(2.0, math.sqrt(n / 4.0))},
        "neighbours": {"radius": 1.0},
        "initial": {"kind": "random", "N": n},
        "time": {"steps": steps, "dt": 1.0},
        "recording": {"observables_every": 10},
        "seed": seed,
    })


def steps_for(path: str, n: int, replicas: int) -> int:
    """Enough steps for about a second of work on each schedule, at least 20."""
    per_agent_step = {"per_step": 2e-6 + 2e-3 / n, "fused": 3e-7, "batched": 3e-7}[path]
    return max(20, min(2000, int(1.0 / (per_agent_step * n * replicas))))


def cell(path: str, n: int, replicas: int) -> dict:
    from flocklab import kernels
    from flocklab.kernels import engine

    steps = steps_for(path, n, replicas)
    scs = [scenario(n, seed, steps) for seed in range(1, replicas + 1)]
    kernels.run_batch([scenario(n, 1, 3)], path=path)  # compile
    t0 = time.perf_counter()
    res = kernels.run_batch(scs, path=path)
    wall = time.perf_counter() - t0
    assert all(r.status == "completed" and r.extra["engine_path"] == path for r in res)
    auto = {r.extra["engine_path"] for r in kernels.run_batch(
        [scenario(n, seed, 2) for seed in range(1, replicas + 1)])}
    return {"bench": "schedules", "N": n, "replicas": replicas, "path": path,
            "steps": steps, "wall_us_per_step": round(1e6 * wall / steps, 1),
            "ns_per_agent_step": round(1e9 * wall / (steps * n * replicas), 1),
            "auto": "+".join(sorted(auto)), "groups": len(engine._batches(scs, path))}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[100, 1000, 10_000])
    ap.add_argument("--replicas", type=int, nargs="+", default=[1, 16, 64])
    ap.add_argument("--paths", nargs="+", default=list(SCHEDULES), choices=SCHEDULES)
    ap.add_argument("--backend", default="cpu", choices=["cpu", "cuda", "vulkan"])
    args = ap.parse_args(argv)
    global BACKEND
    BACKEND = args.backend
    for n in args.sizes:
        for b in args.replicas:
            for path in args.paths:
                print(json.dumps(cell(path, n, b)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
