"""M4 small-N benchmark: the fused path against the per-step path, one JSON line each.

    python -m bench.formation_small_n            # N = 5, 20, 100, 1000, then a preset
    python -m bench.formation_small_n --sizes 5 100 --preset-steps 0
    python -m bench.formation_small_n --dim 3 --preset-steps 0   # the same in 3D
    python -m bench.formation_small_n --dim 3 --preset-steps 0 --observables V2 D1 D2

Single runs: the xi-abed-sim3 scenario (F2, linear f, inverse g, d = 20, dt = 0.01,
observables every 20 steps, no frames) with N agents on a box of side 50 sqrt(N / 100)
(the preset's density) and `max_exact_candidates: null` (always exact, so that N = 1000
may take the fused path too), through `kernels.run`, compile excluded by a warm-up run.
The per-step path is taken with `kernels.run(..., path="per_step")`. Then a preset
(xi-abed-sim1 by default) at 10^4 steps on both paths. `--dim 3`: the agents in a cube of
side 50 (N / 100)^(1/3), the leader's target (-40, -40, -40); F2's D3 is then the host's
linear program on the fused path too (kernels/models/formation/fused.py), unless
`--observables` (the single runs' `recording.observables`) leaves it out. Wall and CPU time
(`time.process_time`, all threads) with the load average beside them: the machine is
shared.
"""

from __future__ import annotations

import argparse
import json
import os
import time


def scenario(n: int, steps: int, dim: int = 2, observables: list[str] | None = None):
    from flocklab.schemas import Scenario, get_preset

    base = get_preset("xi-abed-sim3").model_dump(mode="json")
    side = 50.0 * (n / 100.0) ** (1 / dim)
    base["model"]["max_exact_candidates"] = None
    base["model"]["path"]["target"] = [-40.0] * dim
    base["space"]["dimension"] = dim
    base["initial"] = {"kind": "random", "N": n,
                       "region": {"kind": "box", "low": [0.0] * dim, "high": [side] * dim}}
    base["time"]["steps"] = steps
    base["recording"] = {"every": 0, "observables_every": 20, "observables": observables}
    return Scenario.model_validate(base)


def timed(sc, fused: bool) -> dict:
    from flocklab import kernels

    load = os.getloadavg()[0]
    w0, c0 = time.perf_counter(), time.process_time()
    res = kernels.run(sc, path="fused" if fused else "per_step")
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    assert res.status == "completed", res.error
    assert res.extra["engine_path"] == ("fused" if fused else "per_step")
    steps = sc.time.steps
    return {"path": res.extra["engine_path"], "N": sc.n_agents, "steps": steps,
            "wall_s": round(wall, 3), "cpu_s": round(cpu, 3),
            "us_per_step_wall": round(1e6 * wall / steps, 1),
            "us_per_step_cpu": round(1e6 * cpu / steps, 1), "load_1min": load}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[5, 20, 100, 1000])
    ap.add_argument("--fused-steps", type=int, default=4000)
    ap.add_argument("--per-step-steps", type=int, default=400)
    ap.add_argument("--preset", default="xi-abed-sim1")
    ap.add_argument("--preset-steps", type=int, default=10_000)
    ap.add_argument("--dim", type=int, choices=(2, 3), default=2, help="the single runs' dimension")
    ap.add_argument("--observables", nargs="+", default=None, metavar="NAME",
                    help="the single runs' recording.observables (default: all)")
    args = ap.parse_args()
    from flocklab.kernels import runtime
    from flocklab.schemas import get_preset

    runtime.ensure("cpu")
    for fused in (True, False):  # compile both paths' kernels first
        timed(scenario(8, 40, args.dim), fused)
    for n in args.sizes:
        for fused, steps in ((True, args.fused_steps), (False, args.per_step_steps)):
            row = timed(scenario(n, steps, args.dim, args.observables), fused)
            print(json.dumps({"dim": args.dim, "observables": args.observables, **row}),
                  flush=True)
    if args.preset_steps:
        sc = get_preset(args.preset)
        sc = sc.model_copy(update={
            "time": sc.time.model_copy(update={"steps": args.preset_steps}),
            "recording": sc.recording.model_copy(update={"every": 0})})
        for fused in (True, False):
            print(json.dumps({"preset": args.preset, **timed(sc, fused)}), flush=True)


if __name__ == "__main__":
    main()
