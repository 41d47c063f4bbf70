"""Flocking benchmark workloads: M2 with switching topology and M3 with obstacles.

Agents start on a jittered square lattice of spacing 1 (the `lattice` region; density 1
per unit area, the potential's desired distance d = 1; uniform random positions would put
some pairs at ~1e-6 apart at N = 10^6, where the pair force 1/s^3 is meaningless), with small random
velocities, on the plane, R = 2: about 12 neighbours within R and 36 candidates in the
3x3 cells, as Vicsek's workload (density 4, r = 1). M3 adds N/100 point obstacles in
lattice holes and a destination at the lattice centre. Observables every 10 steps, as for
Vicsek; lambda_2 off (lambda2_max_agents = 0).
"""

import math

import numpy as np


def _common(n: int, seed: int) -> dict:
    return {
        "space": {"kind": "plane"},
        "neighbours": {"radius": 2.0},
        "initial": {"kind": "random", "N": n, "speed_range": [0.0, 0.1],
                    "region": {"kind": "lattice", "spacing": 1.0, "jitter": 0.2}},
        "time": {"steps": 10, "dt": 0.01},
        "recording": {"observables_every": 10},
        "seed": seed,
    }


def flocking_switching(n: int) -> dict:
    return {
        "name": f"bench-flocking-switching-{n}",
        "model": {"kind": "flocking", "topology": "switching",
                  "potential": {"kind": "log_barrier", "d": 1.0}, "lambda2_max_agents": 0},
        **_common(n, 1),
    }


def flocking_obstacles(n: int) -> dict:
    side = math.ceil(math.sqrt(n))
    rng = np.random.default_rng(3)
    holes = rng.choice(n, size=max(1, n // 100), replace=False)
    obstacles = np.stack([holes % side, holes // side], axis=1) + 0.5
    return {
        "name": f"bench-flocking-obstacles-{n}",
        "model": {"kind": "flocking_obstacles", "destination": [side / 2, side / 2],
                  "obstacles": obstacles.tolist(), "lambda2_max_agents": 0},
        **_common(n, 2),
    }


WORKLOADS = [
    ("flocking/switching", flocking_switching),
    ("flocking_obstacles/obstacles", flocking_obstacles),
]
