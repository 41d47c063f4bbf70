"""3D against 2D, in one process per model: agent-steps per second and peak memory.

    python -m bench.dimensions                       # Vicsek, float64 and float32, 10^6
    python -m bench.dimensions --models vicsek flocking formation --precision float64
    python -m bench.dimensions --n 100000 --steps 10
    python -m bench.dimensions --rounds 3            # 2D, 3D, 2D, 3D, ...: a ratio a round

Vicsek: density 4, r = 1 strict, full noise, v0 = 0.5 (the hand-written peer kernel's
workload; bench/peer.py runs the peer beside it).
Flocking (switching topology) and formation (F1, F2): the workloads of bench/bench.py
(bench/workload_flocking.py, bench/workload_formation.py) and their 3D counterparts, the
same with a third coordinate: the lattice of spacing 1 becomes a cubic one (about 30
neighbours within R = 2 against 11 in 2D, jitter included; `flocking/switching-equal-cells`
spaces it 2^(1/3) apart: 4 agents per R^3 as the square lattice has 4 per R^2, about 17
neighbours, its 2D twin unchanged), the formation's square of
one agent per d^2 a cube of one per d^3, its hexagonal formation a cubic lattice, its
leader's target (x, 0, 0). The rate is the difference of a 5-step and a (5 + STEPS)-step
run, which cancels set-up: meant for N >= 10^5, where the steps dominate. Each (model,
dimension, precision) runs in a fresh process; its memory is counted as bench/bench.py
counts it (bench/memory.py): the peak resident memory of one 5-step run at N, less that of
the process warmed at 20000 agents (imports, Taichi, compiled kernels), divided by N.

On a shared machine a single rate drifts by 10-20 % from one minute to the next, so a
ratio of two processes run a minute apart carries that drift: `--rounds K` runs the pair
(2D, then 3D) K times in turn and prints each round's ratio and their median.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time

from bench import memory, workload_flocking, workload_formation


def vicsek(n: int, dim: int) -> dict:
    return {
        "model": {"kind": "vicsek", "rule": "vicsek", "v0": 0.5, "eta": 6.283185307179586,
                  "track_linked_intervals": False},
        "space": {"kind": "periodic", "L": (n / 4) ** (1 / dim), "dimension": dim},
        "neighbours": {"radius": 1.0, "inclusive": False},  # the peer's strict |r_ij| < r
        "initial": {"kind": "random", "N": n},
        "time": {"steps": 10, "dt": 1.0},
        "recording": {"every": 0},
        "seed": 1}


def flocking(n: int, dim: int, spacing_3d: float = 1.0) -> dict:
    doc = workload_flocking.flocking_switching(n)
    doc.pop("name")
    doc["space"]["dimension"] = dim
    if dim == 3:
        doc["initial"]["region"]["low"] = [0.0, 0.0, 0.0]  # the cubic lattice
        doc["initial"]["region"]["spacing"] = spacing_3d
        doc["model"]["potential"]["d"] = spacing_3d  # the lattice at the desired distance
    return doc


def flocking_equal_cells(n: int, dim: int) -> dict:
    """The 3D flock at the 2D one's density in agents per R^d, the convention of the Vicsek
    comparison (density 4 per r^d in both dimensions): the square lattice of spacing 1 holds
    4 agents per R^2 (R = 2), a cubic lattice of spacing 2^(1/3) (and d = 2^(1/3)) 4 per
    R^3. About 17 neighbours within R (spacing 1: about 30; the square lattice: 11)."""
    return flocking(n, dim, 2.0 ** (1.0 / 3.0))


def formation(design: str):
    def make(n: int, dim: int) -> dict:
        doc = workload_formation.f1(n) if design == "F1" else workload_formation.f2(n)
        doc.pop("name")
        if dim == 3:
            half = workload_formation.D * n ** (1 / 3) / 2.0
            doc["space"]["dimension"] = 3
            doc["initial"]["region"] = {"kind": "box", "low": [-half] * 3, "high": [half] * 3}
            doc["model"]["path"]["target"] = [half, 0.0, 0.0]
            if design == "F1":
                doc["model"]["formation"] = {"kind": "named", "shape": "cube"}
        return doc
    return make


MODELS = {"vicsek": [("vicsek", vicsek)],
          "flocking": [("flocking/switching", flocking),
                       ("flocking/switching-equal-cells", flocking_equal_cells)],
          "formation": [("formation/F1", formation("F1")), ("formation/F2", formation("F2"))]}


def one(label: str, n: int, dim: int, steps: int, precision: str) -> dict:
    """Rate and peak memory of one configuration (run in a fresh process)."""
    from flocklab import kernels
    from flocklab.schemas import Scenario

    make = dict(w for ws in MODELS.values() for w in ws)[label]

    def scenario(size: int, k: int) -> Scenario:
        doc = make(size, dim)
        doc["time"]["steps"] = k
        doc["recording"] = {"every": 0, "observables_every": k}
        doc["precision"] = precision
        return Scenario.model_validate(doc)

    # The memory: one run of 5 steps (set-up and two observations) in the warmed process.
    res, per_agent = memory.measured_run(scenario, n, 5)
    if res.status != "completed":
        return {"model": label, "dim": dim, "status": res.status, "error": res.error}
    times = []
    for k in (5, 5 + steps):  # the difference cancels set-up and the first observation
        t = time.perf_counter()
        res = kernels.run(scenario(n, k))
        times.append(time.perf_counter() - t)
        if res.status != "completed":
            return {"model": label, "dim": dim, "status": res.status, "error": res.error}
    return {"model": label, "dim": dim, "precision": precision, "N": n, "steps": steps,
            "engine_path": res.extra["engine_path"],
            "agent_steps_per_s": round(n * steps / (times[1] - times[0])),
            "bytes_per_agent": round(per_agent)}


def run_one(label: str, dim: int, precision: str, n: int, steps: int) -> dict:
    """`one` in a fresh process: its JSON line."""
    out = subprocess.run(
        [sys.executable, "-m", "bench.dimensions", "--one", label, str(dim), precision,
         "--n", str(n), "--steps", str(steps)],
        capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", nargs="+", choices=list(MODELS), default=["vicsek"])
    ap.add_argument("--precision", nargs="+", choices=["float64", "float32"],
                    default=["float64", "float32"])
    ap.add_argument("--n", type=int, default=1_000_000)
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--rounds", type=int, default=1,
                    help="run the 2D and 3D processes this many times in turn")
    ap.add_argument("--one", nargs=3, metavar=("LABEL", "DIM", "PRECISION"),
                    help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.one:
        label, dim, precision = args.one
        print(json.dumps(one(label, args.n, int(dim), args.steps, precision)), flush=True)
        return 0
    for precision in args.precision:
        for model in args.models:
            for label, _ in MODELS[model]:
                ratios = []
                for k in range(args.rounds):
                    rates = {}
                    for dim in (2, 3):
                        line = run_one(label, dim, precision, args.n, args.steps)
                        rates[dim] = line.get("agent_steps_per_s")
                        print(json.dumps(dict(line, round=k + 1)), flush=True)
                    if (rates[2] or 0) > 0 and (rates[3] or 0) > 0:
                        ratios.append(round(rates[3] / rates[2], 2))
                        print(json.dumps({"model": label, "precision": precision, "round": k + 1,
                                          "ratio_3d_to_2d": ratios[-1]}), flush=True)
                if len(ratios) > 1:
                    print(json.dumps({"model": label, "precision": precision,
                                      "ratios_3d_to_2d": ratios,
                                      "median_ratio_3d_to_2d": statistics.median(ratios)}),
                          flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
