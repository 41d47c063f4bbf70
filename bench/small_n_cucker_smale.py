"""Small-N benchmark of Cucker–Smale: the fused schedule against the per-step one, and the
preset's flocking figure.

    python -m bench.small_n_cucker_smale               # per-step cost at N = 20, 100, 1000
    python -m bench.small_n_cucker_smale --figure OUT.png   # cucker-smale-2007's decay

One JSON line per measurement: wall and CPU time (`time.process_time`) per step on each
schedule and their ratio, with the load average beside them (the machine is shared).
Scenarios are the preset at N agents (its initial box grown with N at the preset's
density), observables every 10 steps, no frames, one thread; compile and kernel loading
excluded by a warm-up run. `--integrator rk4` and `--cutoff R` vary the model.
`--figure`: the preset on the schedule auto picks, the velocity and position diameters
against time on a log scale, and a JSON line with their values and the fitted decay rate.
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import os
import time

import numpy as np

from flocklab.schemas import PRESETS, Scenario

SIZES = [20, 100, 1000]


def preset_like(n: int, steps: int, integrator: str, cutoff: float | None) -> Scenario:
    spec = copy.deepcopy(PRESETS["cucker-smale-2007"].build())
    spec["time"]["steps"] = steps
    spec["model"].update(integrator=integrator, cutoff=cutoff)
    spec["recording"] = {"every": 0, "observables_every": 10}
    spec["threads"] = 1
    half = 5.0 * math.sqrt(n / spec["initial"]["N"])
    spec["initial"].update(N=n, region={"kind": "box", "low": [-half] * 2,
                                        "high": [half] * 2})
    return Scenario.model_validate(spec)


def timed(sc: Scenario, path: str) -> tuple[float, float]:
    from flocklab import kernels

    kernels.run(sc.model_copy(update={"time": sc.time.model_copy(update={"steps": 20})}),
                path=path)  # compile and load
    t0, c0 = time.perf_counter(), time.process_time()
    kernels.run(sc, path=path)
    return time.perf_counter() - t0, time.process_time() - c0


def sizes(integrator: str, cutoff: float | None) -> None:
    for n in SIZES:
        steps = max(200, min(20_000, 2_000_000 // n))
        sc = preset_like(n, steps, integrator, cutoff)
        line = {"N": n, "steps": steps, "integrator": integrator, "cutoff": cutoff}
        for path in ("per_step", "fused"):
            wall, cpu = timed(sc, path)
            line[f"{path}_us_per_step"] = round(1e6 * wall / steps, 1)
            line[f"{path}_cpu_us_per_step"] = round(1e6 * cpu / steps, 1)
        line["speedup"] = round(line["per_step_us_per_step"] / line["fused_us_per_step"], 1)
        line["load"] = os.getloadavg()[0]
        print(json.dumps(line), flush=True)


def figure(out: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from flocklab import kernels
    from flocklab.schemas import get_preset

    sc = get_preset("cucker-smale-2007")
    res = kernels.run(sc)
    obs = res.observables
    t, vd, xd = obs["time"], obs["velocity_diameter"], obs["position_diameter"]
    fit = (t > 5) & (vd > 1e-12)  # past the transient, above rounding
    rate = -np.polyfit(t[fit], np.log(vd[fit]), 1)[0]
    fig, ax = plt.subplots(2, 1, figsize=(6.4, 4.8), sharex=True)
    ax[0].semilogy(t, vd)
    ax[0].set_ylabel("velocity diameter")
    ax[0].set_title(f"cucker-smale-2007 (N = {sc.n_agents}, beta = 0.25): "
                    f"decay rate {rate:.3f}")
    ax[1].plot(t, xd)
    ax[1].set_ylabel("position diameter")
    ax[1].set_xlabel("time")
    fig.tight_layout()
    fig.savefig(out, dpi=100)
    at = {f"t={x:g}": float(vd[np.searchsorted(t, x)]) for x in (0, 10, 25, 50, 100)}
    print(json.dumps({"preset": "cucker-smale-2007", "path": res.extra["engine_path"],
                      "velocity_diameter": at, "decay_rate": round(float(rate), 4),
                      "position_diameter_min_max": [float(xd.min()), float(xd.max())],
                      "figure": out}))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--figure", metavar="OUT", help="write the preset's decay figure")
    ap.add_argument("--integrator", default="semi_implicit_euler",
                    choices=["semi_implicit_euler", "rk4"])
    ap.add_argument("--cutoff", type=float)
    args = ap.parse_args(argv)
    from flocklab.kernels import runtime

    runtime.ensure("cpu", threads=1)
    if args.figure:
        figure(args.figure)
    else:
        sizes(args.integrator, args.cutoff)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
