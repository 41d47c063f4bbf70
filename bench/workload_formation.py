"""Benchmark workloads for M4 (Xi–Abed formation control), F1 and F2, for `bench/bench.py`.

Both start N agents uniformly in a square of side d sqrt(N) (one agent per d^2, the density
of Simulation 1) on the plane, with the paper's d = 20, linear f (k = 1) and
g = -k_g (1/s - 1/d) (k_g = 100), explicit Euler. F1 assigns a hexagonal lattice
formation, dt = 0.01; F2 has one virtual leader and squeezes the agents towards it, into a
state too stiff for dt = 0.01 (measured: it diverges at N = 10^4 from t ~ 3), so dt = 0.002.
The leader leaves the initial centroid at speed 5. Observables every 10 steps, as in the
Vicsek workload. bench.py sets the number of steps (t = 0.3 at N = 10^6 with 30 steps: the
swarm is still sparse; a long F2 run at 10^4 reaches the dense regime, docs/models/formation.md).
"""

from __future__ import annotations

import math
from collections.abc import Callable

D = 20.0
STEPS = 50
OBSERVE_EVERY = 10


def _base(n: int, design: str) -> dict:
    half = D * math.sqrt(n) / 2.0
    model: dict = {
        "kind": "formation",
        "design": design,
        "attraction": {"kind": "linear", "k": 1.0},
        "repulsion": {"kind": "inverse", "k_g": 100.0},
        "path": {"kind": "straight", "target": [half, 0.0], "speed": 5.0},
    }
    if design == "F1":
        model["formation"] = {"kind": "named", "shape": "hex"}
    return {
        "name": f"formation-{design.lower()}-bench",
        "model": model,
        "space": {"kind": "plane"},
        "neighbours": {"radius": D},
        "initial": {"kind": "random", "N": n,
                    "region": {"kind": "box", "low": [-half, -half], "high": [half, half]}},
        "time": {"steps": STEPS, "dt": 0.01 if design == "F1" else 0.002},
        "recording": {"every": 0, "observables_every": OBSERVE_EVERY},
        "seed": 7,
    }


def f1(n: int) -> dict:
    return _base(n, "F1")


def f2(n: int) -> dict:
    return _base(n, "F2")


WORKLOADS: list[tuple[str, Callable[[int], dict]]] = [
    ("formation/F1", f1),
    ("formation/F2", f2),
]
