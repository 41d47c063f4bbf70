"""Small-N benchmark of Olfati-Saber: the fused schedule against the per-step one, and the
presets' figures.

    python -m bench.small_n_olfati_saber                 # per-step cost at N = 20, 100, 500
    python -m bench.small_n_olfati_saber --figure OUT.png    # the three presets' measures

One JSON line per measurement: wall and CPU time (`time.process_time`) per step on each
schedule and their ratio, with the load average beside them (the machine is shared).
Scenarios are the olfati-saber-2006-alg2 preset at N agents (its initial box grown with
N at the preset's density), observables every 10 steps, no frames, one thread; compile
and kernel loading excluded by a warm-up run. `--algorithm 3` takes the alg3 preset.
`--figure`: the three presets on the schedule auto picks, deviation energy, relative
connectivity and (Algorithm 3) the minimum obstacle distance against time, and a JSON
line per preset with the final values.
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import os
import time

from flocklab.schemas import PRESETS, Scenario

SIZES = [20, 100, 500]  # the fused schedule covers N <= 512
PRESET = {2: "olfati-saber-2006-alg2", 3: "olfati-saber-2006-alg3"}


def preset_like(n: int, steps: int, algorithm: int) -> Scenario:
    spec = copy.deepcopy(PRESETS[PRESET[algorithm]].build())
    spec["time"]["steps"] = steps
    spec["recording"] = {"every": 0, "observables_every": 10}
    spec["threads"] = 1
    region = spec["initial"]["region"]
    grow = math.sqrt(n / spec["initial"]["N"])
    mid = [(lo + hi) / 2 for lo, hi in zip(region["low"], region["high"], strict=True)]
    half = [(hi - lo) / 2 * grow for lo, hi in zip(region["low"], region["high"],
                                                   strict=True)]
    region.update(low=[m - h for m, h in zip(mid, half, strict=True)],
                  high=[m + h for m, h in zip(mid, half, strict=True)])
    spec["initial"]["N"] = n
    return Scenario.model_validate(spec)


def timed(sc: Scenario, path: str) -> tuple[float, float]:
    from flocklab import kernels

    kernels.run(sc.model_copy(update={"time": sc.time.model_copy(update={"steps": 20})}),
                path=path)  # compile and load
    t0, c0 = time.perf_counter(), time.process_time()
    kernels.run(sc, path=path)
    return time.perf_counter() - t0, time.process_time() - c0


def sizes(algorithm: int) -> None:
    for n in SIZES:
        steps = max(200, min(5_000, 500_000 // n))
        sc = preset_like(n, steps, algorithm)
        line = {"N": n, "steps": steps, "algorithm": algorithm}
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

    names = ["olfati-saber-2006-alg1", "olfati-saber-2006-alg2", "olfati-saber-2006-alg3"]
    fig, ax = plt.subplots(3, 1, figsize=(6.4, 7.2), sharex=False)
    for colour, name in enumerate(names):
        sc = get_preset(name)
        res = kernels.run(sc)
        o = res.observables
        t = o["time"]
        ax[0].semilogy(t, o["deviation_energy"], f"C{colour}", label=name)
        ax[1].plot(t, o["relative_connectivity"], f"C{colour}", label=name)
        line = {"preset": name, "path": res.extra["engine_path"], "N": sc.n_agents,
                "t_end": float(t[-1])}
        for k in ("deviation_energy", "relative_connectivity", "velocity_mismatch",
                  "cohesion_radius", "leader_distance"):
            if k in o:
                line[k] = float(o[k][-1])
        if "min_obstacle_distance" in o:
            ax[2].plot(t, o["min_obstacle_distance"], f"C{colour}", label=name)
            line["min_obstacle_distance_min"] = float(o["min_obstacle_distance"].min())
        print(json.dumps(line), flush=True)
    ax[0].set_ylabel("deviation energy")
    ax[1].set_ylabel("relative connectivity")
    ax[2].set_ylabel("min obstacle distance")
    ax[2].set_xlabel("time")
    ax[0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out, dpi=100)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--figure", metavar="OUT", help="write the presets' figure")
    ap.add_argument("--algorithm", type=int, default=2, choices=[2, 3])
    args = ap.parse_args(argv)
    from flocklab.kernels import runtime

    runtime.ensure("cpu", threads=1)
    if args.figure:
        figure(args.figure)
    else:
        sizes(args.algorithm)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
