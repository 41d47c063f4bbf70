"""Small-N benchmark of the flocking family (M2, M3): fused path against per-step path.

    python -m bench.small_n_flocking            # per-step cost at N = 5, 20, 100, 1000
                                                # and the 10^4-step presets, both paths
    python -m bench.small_n_flocking --sizes    # the per-N table only
    python -m bench.small_n_flocking --sizes --dim 3   # the same flocks in 3D
    python -m bench.small_n_flocking --sizes --dim 3 --observables Q W components
    python -m bench.small_n_flocking --m3-3d    # tanner-obstacles made 3D at N = 100
    python -m bench.small_n_flocking --sizes --integrator rk4   # RK4, both paths

One JSON line per measurement: wall and CPU time (`time.process_time`) per step, and the
load average beside them (the machine is shared). Scenarios are preset-like: tjp-switching
(and tjp-fixed) with the initial box grown with N at the preset's density, observables
every 10 steps, no frames, one thread; compile and kernel loading excluded by a warm-up run.
`--dim 3`: the same presets in 3D, the initial box a cube holding the preset's agents per
unit area as agents per unit volume. `--observables`: the per-N runs' recording.observables
(default: all; lambda2, an eigensolve on the host at every observation, only if named).
`--integrator rk4`: the per-N runs with RK4 (fused: its stages in the same launch).
`--m3-3d`: tanner-obstacles in 3D (its wall of point obstacles at z = 0, the destination at
the origin), N agents on a jittered cubic lattice of spacing 1.5 by the preset's start.
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import os
import time

from flocklab.schemas import PRESETS, Scenario

SIZES = [5, 20, 100, 1000]


def preset_like(name: str, n: int, steps: int, dim: int = 2,
                observables: list[str] | None = None,
                integrator: str = "semi_implicit_euler") -> Scenario:
    """The preset at N agents in `dim` dimensions, the initial box (the preset's square of
    side 5) scaled to keep its density."""
    spec = copy.deepcopy(PRESETS[name].build())  # build() shares its nested dicts
    spec["time"]["steps"] = steps
    spec["model"]["integrator"] = integrator
    spec["recording"] = {"every": 0, "observables_every": 10, "observables": observables}
    spec["threads"] = 1
    spec["space"]["dimension"] = dim
    init = spec["initial"]
    if n != init["N"] or dim != 2:
        half = 0.5 * (25.0 * n / init["N"]) ** (1 / dim)  # N / 25 agents per unit
        init["N"] = n
        init["region"] = {"kind": "box", "low": [-half] * dim, "high": [half] * dim}
    return Scenario.model_validate(spec)


def tanner_3d(n: int, steps: int) -> Scenario:
    """tanner-obstacles in 3D: the obstacles and destination at z = 0, a jittered cubic
    lattice of N agents (spacing 1.5, speeds below 0.1) from (-4.5, -4.5, 0) - m / 2, m the
    agents along an edge: at N = 100 most of them pass the wall and reach V <= V_min
    within 3000 steps."""
    spec = copy.deepcopy(PRESETS["tanner-obstacles"].build())
    model = spec["model"]
    model["obstacles"] = [[x, y, 0.0] for x, y in model["obstacles"]]
    model["destination"] = [*model["destination"], 0.0]
    side = math.ceil(n ** (1 / 3) - 1e-9)
    spec["space"]["dimension"] = 3
    spec["initial"] = {"kind": "random", "N": n, "speed_range": [0.0, 0.1],
                       "region": {"kind": "lattice", "spacing": 1.5, "jitter": 0.2,
                                  "low": [-4.5 - side / 2, -4.5 - side / 2, -side / 2]}}
    spec["time"]["steps"] = steps
    spec["recording"] = {"every": 0, "observables_every": 10}
    spec["threads"] = 1
    return Scenario.model_validate(spec)


def timed(sc: Scenario, fused: bool) -> dict:
    from flocklab import kernels

    path = "fused" if fused else "per_step"
    kernels.run(Scenario.model_validate({**sc.model_dump(mode="json"),
                                         "time": {"steps": 2, "dt": sc.time.dt}}), path=path)
    w0, c0 = time.perf_counter(), time.process_time()
    res = kernels.run(sc, path=path)
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    assert res.extra["engine_path"] == ("fused" if fused else "per_step")
    return {"path": res.extra["engine_path"], "status": res.status, "steps": res.steps,
            "wall_s": round(wall, 4), "cpu_s": round(cpu, 4),
            "us_per_step_wall": round(1e6 * wall / sc.time.steps, 1),
            "us_per_step_cpu": round(1e6 * cpu / sc.time.steps, 1),
            "agent_steps_per_s_cpu": round(sc.n_agents * sc.time.steps / cpu),
            "loadavg_1min": os.getloadavg()[0]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", action="store_true", help="the per-N table only")
    ap.add_argument("--dim", type=int, choices=(2, 3), default=2,
                    help="the flocks' dimension (the per-N table)")
    ap.add_argument("--m3-3d", action="store_true", help="3D tanner-obstacles at N = 100 only")
    ap.add_argument("--observables", nargs="+", default=None, metavar="NAME",
                    help="the per-N runs' recording.observables (default: all)")
    ap.add_argument("--integrator", choices=("semi_implicit_euler", "rk4"),
                    default="semi_implicit_euler", help="the per-N runs' integrator")
    args = ap.parse_args()
    from flocklab.kernels import runtime

    runtime.ensure("cpu", 1)
    if args.m3_3d:
        for fused in (True, False):
            row = timed(tanner_3d(100, 3000 if fused else 300), fused)
            print(json.dumps({"scenario": "tanner-obstacles-3d", "N": 100, **row}), flush=True)
        return
    for n in SIZES:
        for name in ("tjp-switching", "tjp-fixed"):
            for fused in (True, False):
                steps = (3000 if n <= 100 else 1000) if fused else 300
                sc = preset_like(name, n, steps, args.dim, args.observables, args.integrator)
                print(json.dumps({"scenario": name, "dim": args.dim, "N": n,
                                  "integrator": args.integrator,
                                  "observables": args.observables, **timed(sc, fused)}),
                      flush=True)
    if args.sizes:
        return
    for name in ("tjp-switching", "tjp-fixed", "tanner-obstacles"):
        spec = PRESETS[name].build()
        spec["recording"]["every"] = 0  # no trajectory file here
        spec["threads"] = 1
        sc = Scenario.model_validate(spec)
        for fused in (True, False):
            print(json.dumps({"scenario": name, "preset": True, "N": sc.n_agents,
                              **timed(sc, fused)}), flush=True)


if __name__ == "__main__":
    main()
