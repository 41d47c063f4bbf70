"""Small-N benchmark (the sweeps issue's bar): one JSON line per measurement.

    python -m bench.small_n                 # single runs at N = 10, 100, 1000, 4000, then
                                            # the reduced Fig. 2a sweep, both implementations
    python -m bench.small_n --single        # single runs only
    python -m bench.small_n --sweep-only    # the reduced Fig. 2a sweep only
    python -m bench.small_n --full-fig2a    # also time the full Fig. 2a protocol preset

Single runs: Vicsek rule, density 4, r = 1 (<=), eta = 0.5, new-heading move, 3000 steps,
observables every step (all of the model's, then the polarization alone, which is what the
baseline computes), one thread, through `kernels.run` (compile excluded by a warm-up run),
against the numpy + scipy cKDTree step with its polarization every step.
The reduced Fig. 2a sweep: eta = 0.5 ... 5.0 (step 0.5) x (N, L) = (100, 5), (400, 10),
4 replicas, 3000 steps, polarization mean from step 1000, through `flocklab sweep` (a
fresh process, compile and start-up included) against the cKDTree script doing the same
sweep serially; both tables are printed and compared within seed noise.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ETAS = [round(0.5 * k, 1) for k in range(1, 11)]
SIZES = [(100, 5.0), (400, 10.0)]
REPLICAS, STEPS, FROM_STEP = 4, 3000, 1000


def vicsek_scenario(n: int, L: float, eta: float, steps: int, seed: int = 1,
                    every: int = 1) -> dict:
    return {
        "model": {"kind": "vicsek", "rule": "vicsek", "v0": 0.03, "eta": eta,
                  "position_update": "new_heading"},
        "space": {"kind": "periodic", "L": L},
        "neighbours": {"radius": 1.0, "inclusive": True},
        "initial": {"kind": "random", "N": n},
        "time": {"steps": steps, "dt": 1.0},
        "recording": {"observables_every": every},
        "seed": seed,
        "threads": 1,
    }


def single(sizes: list[int], steps: int) -> None:
    from bench import ckdtree_vicsek
    from flocklab import kernels
    from flocklab.schemas import Scenario

    for n, chosen in ((n, c) for n in sizes for c in (None, ["polarization"])):
        L = math.sqrt(n / 4.0)
        if L < 2.0:
            L = 2.0  # the periodic box needs r <= L / 2
        doc = vicsek_scenario(n, L, 0.5, steps)
        doc["recording"]["observables"] = chosen  # None: every observable of the model
        sc = Scenario.model_validate(doc)
        kernels.run(sc.model_copy(update={"time": sc.time.model_copy(update={"steps": 5})}))
        res = kernels.run(sc)
        ours = (res.wall_seconds - res.extra["setup_seconds"]) / res.steps
        base_steps = max(50, min(steps, int(2e6 / n)))
        t0 = time.perf_counter()
        ckdtree_vicsek.polarization(n, L, 0.5, base_steps, seed=1)
        theirs = (time.perf_counter() - t0) / base_steps
        print(json.dumps({
            "bench": "single-run", "N": n, "steps": steps, "observables_every": 1,
            "observables": "all" if chosen is None else ",".join(chosen),
            "engine_path": res.extra["engine_path"],
            "flocklab_us_per_step": round(ours * 1e6, 2),
            "ckdtree_us_per_step": round(theirs * 1e6, 2),
            "speedup": round(theirs / ours, 2),
        }), flush=True)


def sweep_spec() -> dict:
    base = vicsek_scenario(100, 5.0, 0.5, STEPS)
    del base["threads"]  # the sweep uses every core
    # As a user writes it: no observables list (keep "table": the runs compute what the
    # measure reads, the polarization, which is what the cKDTree script computes).
    return {
        "name": "bench-fig2a-reduced",
        "base": base,
        "axes": [
            {"path": "model.eta", "values": ETAS},
            {"zip": [{"path": "initial.N", "values": [n for n, _ in SIZES]},
                     {"path": "space.L", "values": [L for _, L in SIZES]}]},
        ],
        "replicas": REPLICAS,
        "measure": {"va": {"observable": "polarization", "reduce": "mean",
                           "from_step": FROM_STEP}},
        "keep": "table",
    }


def read_table(path: Path) -> dict[tuple[float, int], float]:
    with open(path, newline="") as fh:
        return {(float(r["model.eta"]), int(float(r["initial.N"]))): float(r["va_mean"])
                for r in csv.DictReader(fh)}


def baseline_sweep() -> dict[tuple[float, int], tuple[float, float]]:
    """The same sweep with the cKDTree script, serially: (eta, N) -> (mean, sem)."""
    from bench import ckdtree_vicsek

    out = {}
    for eta in ETAS:
        for n, L in SIZES:
            va = [ckdtree_vicsek.polarization(n, L, eta, STEPS, seed=1000 + k)[FROM_STEP:].mean()
                  for k in range(REPLICAS)]
            out[(eta, n)] = (float(np.mean(va)), float(np.std(va, ddof=1) / math.sqrt(REPLICAS)))
    return out


def fig2a_sweep() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        spec = Path(tmp) / "sweep.json"
        spec.write_text(json.dumps(sweep_spec()))
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "flocklab", "sweep", str(spec),
                        "--out", str(Path(tmp) / "out")], check=True,
                       stdout=subprocess.DEVNULL)
        ours_s = time.perf_counter() - t0
        ours = read_table(Path(tmp) / "out" / "table.csv")
    t0 = time.perf_counter()
    theirs = baseline_sweep()
    theirs_s = time.perf_counter() - t0
    # Within seed noise: each cell's difference against the two tables' combined error.
    z = [abs(ours[k] - m) / max(math.sqrt(2) * se, 1e-3) for k, (m, se) in theirs.items()]
    print(json.dumps({
        "bench": "fig2a-reduced-sweep", "runs": len(ETAS) * len(SIZES) * REPLICAS,
        "steps": STEPS, "flocklab_sweep_seconds": round(ours_s, 2),
        "ckdtree_serial_seconds": round(theirs_s, 2), "speedup": round(theirs_s / ours_s, 2),
        "table": {f"eta={e},N={n}": [round(ours[(e, n)], 4), round(theirs[(e, n)][0], 4)]
                  for e, n in sorted(theirs)},
        "max_abs_diff": round(max(abs(ours[k] - theirs[k][0]) for k in theirs), 4),
        "max_z": round(max(z), 2),
    }), flush=True)


def full_fig2a() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "flocklab", "sweep", "preset:vicsek-1995-fig2a",
                        "--out", str(Path(tmp) / "out")], check=True, stdout=subprocess.DEVNULL)
        print(json.dumps({"bench": "fig2a-full-protocol",
                          "seconds": round(time.perf_counter() - t0, 1)}), flush=True)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[10, 100, 1000, 4000])
    ap.add_argument("--steps", type=int, default=3000)
    only = ap.add_mutually_exclusive_group()
    only.add_argument("--single", action="store_true", help="single runs only")
    only.add_argument("--sweep-only", action="store_true",
                      help="the reduced Fig. 2a sweep only (and --full-fig2a if given)")
    ap.add_argument("--full-fig2a", action="store_true", help="also the full protocol")
    args = ap.parse_args(argv)
    if not args.sweep_only:
        single(args.sizes, args.steps)
    if not args.single:
        fig2a_sweep()
        if args.full_fig2a:
            full_fig2a()
    return 0


if __name__ == "__main__":
    sys.exit(main())
