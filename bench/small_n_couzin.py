"""Small-N benchmark of Couzin's model: the fused schedule against the per-step one, and
the four presets' collective states.

    python -m bench.small_n_couzin                    # per-step cost at N = 20, 100, 1000
    python -m bench.small_n_couzin --states [--figure OUT.png]   # couzin-2002-* p and m
    python -m bench.small_n_couzin --memory           # collective memory (hysteresis)

One JSON line per measurement: wall and CPU time (`time.process_time`) per step on each
schedule and their ratio, with the load average beside them (the machine is shared).
Scenarios are couzin-2002-torus at N agents (3D; its initial ball grown with N at the
preset's density), observables every 10 steps, no frames, one thread; compile and kernel
loading excluded by a warm-up run. `--states`: each couzin-2002-* preset on the schedule
auto picks, a line with its polarization p and milling m at the end and averaged over
the last 100 s; `--figure` draws p and m against time for the four. `--memory`: the
paper's collective memory, Delta r_o stepped up from the torus preset's end state and
down from the parallel preset's (each value run MEMORY_SECONDS from the state the last
one ended in, through an explicit initial block), a line per value with p and m averaged
over its last half.
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
MEMORY_SECONDS = 100.0
MEMORY_STEPS = [2.0, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0, 13.0]


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


def continued(spec: dict, pos: np.ndarray, vel: np.ndarray, dr_o: float) -> Scenario:
    """spec at Delta r_o = dr_o, starting from (pos, vel), for MEMORY_SECONDS."""
    spec = copy.deepcopy(spec)
    spec["model"]["dr_o"] = dr_o
    spec["initial"] = {"kind": "explicit", "positions": pos.tolist(),
                       "velocities": vel.tolist()}
    spec["time"]["steps"] = round(MEMORY_SECONDS / spec["time"]["dt"])
    spec["recording"] = {"every": spec["time"]["steps"], "arrays": ["position", "velocity"],
                         "observables_every": 10}
    return Scenario.model_validate(spec)


class Last:
    """A FrameSink keeping the last frame."""

    def frame(self, step, time, arrays):
        self.pos = np.array(arrays["position"])
        self.vel = np.array(arrays["velocity"])


def memory() -> None:
    from flocklab import kernels

    for start, values in (("torus", MEMORY_STEPS), ("parallel", MEMORY_STEPS[::-1])):
        spec = PRESETS[f"couzin-2002-{start}"].build()
        spec["recording"] = {"every": spec["time"]["steps"], "arrays": ["position",
                                                                         "velocity"]}
        sink = Last()
        kernels.run(Scenario.model_validate(spec), sink=sink)
        for dr_o in values:
            res = kernels.run(continued(spec, sink.pos, sink.vel, dr_o), sink=sink)
            o = res.observables
            half = o["time"] >= MEMORY_SECONDS / 2
            print(json.dumps({"from": start, "dr_o": dr_o,
                              "p": round(float(o["polarization"][half].mean()), 3),
                              "m": round(float(o["milling"][half].mean()), 3)}), flush=True)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--states", action="store_true", help="run the four state presets")
    ap.add_argument("--figure", metavar="OUT", help="with --states: draw p and m")
    ap.add_argument("--memory", action="store_true", help="Delta r_o up and down")
    args = ap.parse_args(argv)
    from flocklab.kernels import runtime

    runtime.ensure("cpu", threads=1)
    if args.memory:
        memory()
    elif args.states:
        states(args.figure)
    else:
        sizes()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
