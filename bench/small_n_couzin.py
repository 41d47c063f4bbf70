"""Small-N benchmark of Couzin's model: the fused schedule against the per-step one, and
the four presets' collective states.

    python -m bench.small_n_couzin                    # per-step cost at N = 20, 100, 1000
    python -m bench.small_n_couzin --states [--figure OUT.png]   # couzin-2002-* p and m

One JSON line per measurement: wall and CPU time (`time.process_time`) per step on each
schedule and their ratio, with the load average beside them (the machine is shared).
Scenarios are couzin-2002-torus at N agents (3D; its initial ball grown with N at the
preset's density), observables every 10 steps, no frames, one thread; compile and kernel
loading excluded by a warm-up run. `--states`: each couzin-2002-* preset on the schedule
auto picks, a line with its polarization p and milling m at the end and averaged over
the last 100 s; `--figure` draws p and m against time for the four.
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import time

import numpy as np

from flocklab.schemas import PRESETS, Scenario

SIZES = [20, 100, 1000]
STATES = ("swarm", "torus", "dynamic-parallel", "parallel")


def preset_like(n: int, steps: int) -> Scenario:
    spec = copy.deepcopy(PRESETS["couzin-2002-torus"].build())
    spec["time"]["steps"] = steps
    spec["recording"] = {"every": 0, "observables_every": 10}
    spec["threads"] = 1
    spec["initial"]["N"] = n
    spec["initial"]["region"]["radius"] *= (n / 100) ** (1 / 3)
    return Scenario.model_validate(spec)


def timed(sc: Scenario, path: str) -> tuple[float, float]:
    from flocklab import kernels

    kernels.run(sc.model_copy(update={"time": sc.time.model_copy(update={"steps": 20})}),
                path=path)  # compile and load
    t0, c0 = time.perf_counter(), time.process_time()
    kernels.run(sc, path=path)
    return time.perf_counter() - t0, time.process_time() - c0


def sizes() -> None:
    for n in SIZES:
        steps = max(200, min(5_000, 500_000 // n))
        sc = preset_like(n, steps)
        line = {"N": n, "steps": steps, "dimension": 3}
        for path in ("per_step", "fused"):
            wall, cpu = timed(sc, path)
            line[f"{path}_us_per_step"] = round(1e6 * wall / steps, 1)
            line[f"{path}_cpu_us_per_step"] = round(1e6 * cpu / steps, 1)
        line["speedup"] = round(line["per_step_us_per_step"] / line["fused_us_per_step"], 1)
        line["load"] = os.getloadavg()[0]
        print(json.dumps(line), flush=True)


def states(out: str | None) -> None:
    from flocklab import kernels
    from flocklab.schemas import get_preset

    runs = {}
    for state in STATES:
        sc = get_preset(f"couzin-2002-{state}")
        res = kernels.run(sc)
        o = res.observables
        t, p, m = o["time"], o["polarization"], o["milling"]
        tail = t >= t[-1] - 100.0
        runs[state] = (t, p, m)
        print(json.dumps({"preset": sc.name, "path": res.extra["engine_path"],
                          "dr_o": sc.model.dr_o, "dr_a": sc.model.dr_a,
                          "p_end": round(float(p[-1]), 3), "m_end": round(float(m[-1]), 3),
                          "p_last_100s": round(float(p[tail].mean()), 3),
                          "m_last_100s": round(float(m[tail].mean()), 3)}), flush=True)
    if out:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(len(STATES), 1, figsize=(6.4, 7.2), sharex=True)
        for a, (state, (t, p, m)) in zip(ax, runs.items(), strict=True):
            a.plot(t, p, label="polarization p")
            a.plot(t, m, label="milling m")
            a.set_ylim(0, 1.02)
            a.set_ylabel(state)
        ax[0].legend(loc="lower right", fontsize="small")
        ax[-1].set_xlabel("time (s)")
        fig.suptitle("couzin-2002-* (N = 100, 3D, Delta r_a = 14)")
        fig.tight_layout()
        fig.savefig(out, dpi=100)
        print(json.dumps({"figure": out, "final": {s: [float(np.round(r[1][-1], 3)),
                                                       float(np.round(r[2][-1], 3))]
                                                   for s, r in runs.items()}}))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--states", action="store_true", help="run the four state presets")
    ap.add_argument("--figure", metavar="OUT", help="with --states: draw p and m")
    args = ap.parse_args(argv)
    from flocklab.kernels import runtime

    runtime.ensure("cpu", threads=1)
    if args.states:
        states(args.figure)
    else:
        sizes()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
