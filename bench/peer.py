"""flocklab against the hand-written peer kernel, on the peer's workload, in one sitting.

    python -m bench.peer                                  # N = 10^6, float32 and float64
    python -m bench.peer --sizes 10k 100k 1M --precision float32 --repeats 5

The peer (`../shared/peers/ti_vicsek.py` beside the repository: a float32 Taichi grid
kernel, one launch per step) and flocklab's per-step Vicsek run the same workload
(`../shared/peers/common.py`: periodic L x L, N = 4 L^2, r = 1 strict, v0 = 0.5, full
noise, new-heading update). Rates drift by 20 % between sittings on a shared machine, so
the two alternate, each in a fresh process, `--repeats` times, and the ratio is of the
medians of the same run. The flocklab rate is the difference of the stepping loops (set-up
excluded, as bench/bench.py reports it) of a 3-step and a (3 + STEPS)-step run after a
warm-up at 20000 agents that compiles the kernels, which also cancels the observations;
`flocklab_cpu_seconds_per_step` is the process's CPU time counted the same way: on a
shared machine a truer figure of the work than the wall time. Without the peer
directory the comparison is skipped with a message and exit status 0.

One JSON line per (size, precision):
  {"N", "precision", "flocklab_agent_steps_per_s", "peer_agent_steps_per_s", "ratio", ...}
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

from bench import dimensions, memory

PEER = Path(__file__).resolve().parents[2] / "shared" / "peers" / "ti_vicsek.py"
SIDES = {"10k": 50, "100k": 158, "1M": 500}  # common.SIZES: the peer's box sides
WARM_STEPS = 3


def flocklab_one(n: int, steps: int, precision: str) -> dict:
    """Runs in a fresh process: seconds and CPU seconds per step of the per-step path."""
    from flocklab import kernels
    from flocklab.schemas import Scenario

    def scenario(k: int, size: int = n) -> Scenario:
        doc = dimensions.vicsek(size, 2)
        doc["time"]["steps"] = k
        doc["recording"] = {"every": 0, "observables_every": k}
        doc["precision"] = precision
        return Scenario.model_validate(doc)

    kernels.run(scenario(WARM_STEPS, memory.WARM_N))  # compiles the per-step kernels
    wall, cpu = [], []
    for k in (WARM_STEPS, WARM_STEPS + steps):
        c = time.process_time()
        res = kernels.run(scenario(k))
        # The stepping loop's wall time (set-up excluded: its wall time varies most).
        wall.append(res.wall_seconds - res.extra.get("setup_seconds", 0.0))
        cpu.append(time.process_time() - c)
        if res.status != "completed":
            raise RuntimeError(f"flocklab run {res.status}: {res.error}")
    return {"engine_path": res.extra["engine_path"],
            "seconds_per_step": (wall[1] - wall[0]) / steps,
            "cpu_seconds_per_step": (cpu[1] - cpu[0]) / steps}


def peer_one(size: str) -> dict:
    """One repeat of the peer at `size` (its own JSON line), in a fresh process."""
    env = {**os.environ, "PERF_MAX_WAIT": os.environ.get("PERF_MAX_WAIT", "5")}
    out = subprocess.run([sys.executable, str(PEER), "--sizes", size, "--repeats", "1"],
                         capture_output=True, text=True, check=True, env=env)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", nargs="+", choices=list(SIDES), default=["1M"])
    ap.add_argument("--precision", nargs="+", choices=["float32", "float64"],
                    default=["float32", "float64"])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--steps", type=int, help="flocklab steps per repeat (default 1e7 / N + 10)")
    ap.add_argument("--one", nargs=2, metavar=("N", "PRECISION"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.one:
        n, precision = int(args.one[0]), args.one[1]
        print(json.dumps(flocklab_one(n, args.steps, precision)))
        return 0
    if not PEER.is_file():
        print(json.dumps({"skipped": f"no peer kernel at {PEER}: nothing to compare against"}))
        return 0
    for size in args.sizes:
        n = 4 * SIDES[size] ** 2
        steps = args.steps or 10 + int(1e7 / n)
        peer: list[float] = []
        ours: dict[str, list[dict]] = {p: [] for p in args.precision}
        for _ in range(args.repeats):  # interleaved: drift hits both sides alike
            peer.append(peer_one(size)["agent_steps_per_s"])
            for precision in args.precision:
                out = subprocess.run(
                    [sys.executable, "-m", "bench.peer", "--one", str(n), precision,
                     "--steps", str(steps)], capture_output=True, text=True, check=True)
                ours[precision].append(json.loads(out.stdout.strip().splitlines()[-1]))
        peer_rate = statistics.median(peer)
        for precision, runs in ours.items():
            sec = statistics.median(r["seconds_per_step"] for r in runs)
            rate = n / sec
            print(json.dumps({
                "N": n, "precision": precision, "steps": steps, "repeats": args.repeats,
                "engine_path": runs[-1]["engine_path"],
                "flocklab_agent_steps_per_s": round(rate),
                "flocklab_cpu_seconds_per_step": round(
                    statistics.median(r["cpu_seconds_per_step"] for r in runs), 4),
                "peer_agent_steps_per_s": round(peer_rate),
                "peer_runs": [round(p) for p in peer],
                "flocklab_runs": [round(n / r["seconds_per_step"]) for r in runs],
                "ratio": round(rate / peer_rate, 3)}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
