"""3D against 2D Vicsek, float64 and float32, in one process: agent-steps per second at
density 4, r = 1, full noise, v0 = 0.5 (the hand-written peer kernel's workload).

    python -m bench.dimensions [N] [STEPS]       # default 10^6 agents, 20 steps

The rate is the difference of a 5-step and a (5 + STEPS)-step run, which cancels set-up:
meant for N >= 10^5, where the steps dominate (below, the difference is noise).
"""
import json
import sys
import time

from flocklab import kernels
from flocklab.schemas import Scenario

N = int(sys.argv[1]) if len(sys.argv) > 1 else 1_000_000
STEPS = int(sys.argv[2]) if len(sys.argv) > 2 else 20


def scenario(dim: int, steps: int, precision: str = "float64") -> Scenario:
    L = (N / 4) ** (1 / dim)
    return Scenario.model_validate({
        "model": {"kind": "vicsek", "rule": "vicsek", "v0": 0.5, "eta": 6.283185307179586,
                  "track_linked_intervals": False},
        "space": {"kind": "periodic", "L": L, "dimension": dim},
        "neighbours": {"radius": 1.0},
        "initial": {"kind": "random", "N": N},
        "time": {"steps": steps, "dt": 1.0},
        "recording": {"every": 0, "observables_every": steps},
        "seed": 1, "precision": precision})


for precision in ("float64", "float32"):
    for dim in (2, 3):
        kernels.run(scenario(dim, 2, precision))  # compile
        times = []
        for steps in (5, 5 + STEPS):  # the difference cancels set-up and first observation
            t = time.perf_counter()
            kernels.run(scenario(dim, steps, precision))
            times.append(time.perf_counter() - t)
        dt = times[1] - times[0]
        print(json.dumps({"dim": dim, "precision": precision, "N": N, "steps": STEPS,
                          "agent_steps_per_s": round(N * STEPS / dt)}), flush=True)
