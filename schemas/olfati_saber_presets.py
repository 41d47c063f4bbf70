"""Named Olfati-Saber runs: the paper's section VIII parameters (d = 7, r = 1.2 d,
d' = 0.6 d, r' = 1.2 d', eps = 0.1, h = 0.2 for phi_alpha and 0.9 for phi_beta, a = b = 5)
with 150 agents in the plane; the initial box, speeds, leader and obstacles are chosen
here (docs/models/olfati_saber.md says which values the stored copies let us check)."""

from __future__ import annotations

import math

from .presets import register_preset

PAPER = {"kind": "olfati_saber", "d": 7.0, "kappa": 1.2, "d_obstacle": 4.2,
         "kappa_obstacle": 1.2, "epsilon": 0.1, "h_alpha": 0.2, "h_beta": 0.9,
         "a": 5.0, "b": 5.0}


def _start(n: int, low: list[float], high: list[float]) -> dict:
    return {"kind": "random", "N": n, "region": {"kind": "box", "low": low, "high": high},
            "heading_range": [-math.pi, math.pi], "speed_range": [0.0, 1.0]}


@register_preset(
    "olfati-saber-2006-alg1",
    "Olfati-Saber 2006, Algorithm 1: 150 alpha-agents from a random start in a 60 x 60 "
    "box; the flock generically fragments (relative connectivity < 1), t = 0..40.",
)
def olfati_saber_alg1() -> dict:
    return {
        "name": "olfati-saber-2006-alg1",
        "model": {**PAPER, "algorithm": 1},
        "space": {"kind": "plane"},
        "initial": _start(150, [-30.0, -30.0], [30.0, 30.0]),
        "time": {"steps": 4000, "dt": 0.01},
        "recording": {"every": 400, "arrays": ["position", "velocity"],
                      "observables_every": 20},
        "seed": 11,
    }


@register_preset(
    "olfati-saber-2006-alg2",
    "Olfati-Saber 2006, Algorithm 2: the same start with a gamma-agent (virtual leader) "
    "moving at (1, 0); the agents flock: relative connectivity 1, small deviation "
    "energy, velocities matched, t = 0..80.",
)
def olfati_saber_alg2() -> dict:
    return {
        "name": "olfati-saber-2006-alg2",
        "model": {**PAPER, "algorithm": 2, "c1_gamma": 0.02, "c2_gamma": 0.3,
                  "leader": {"position": [0.0, 0.0], "velocity": [1.0, 0.0]}},
        "space": {"kind": "plane"},
        "initial": _start(150, [-30.0, -30.0], [30.0, 30.0]),
        "time": {"steps": 8000, "dt": 0.01},
        "recording": {"every": 800, "arrays": ["position", "velocity"],
                      "observables_every": 20},
        "seed": 11,
    }


@register_preset(
    "olfati-saber-2006-alg3",
    "Olfati-Saber 2006, Algorithm 3: 150 agents follow a virtual leader at (1, 0) "
    "through the gap between two discs, a wall below (beta-agents); no agent touches an "
    "obstacle (min_obstacle_distance > 0), t = 0..140.",
)
def olfati_saber_alg3() -> dict:
    # OptFlock's alpha and beta gains, c2 = 2 sqrt(c1); c1g = 10, not its 1: at 1 the
    # 150-agent lattice jams in front of the discs (docs/models/olfati_saber.md).
    c1a, c1b, c1g = 30.0, 300.0, 10.0
    return {
        "name": "olfati-saber-2006-alg3",
        "model": {**PAPER, "algorithm": 3,
                  "c1_alpha": c1a, "c2_alpha": 2 * math.sqrt(c1a),
                  "c1_beta": c1b, "c2_beta": 2 * math.sqrt(c1b),
                  "c1_gamma": c1g, "c2_gamma": 2 * math.sqrt(c1g),
                  "leader": {"position": [-40.0, 0.0], "velocity": [1.0, 0.0]},
                  "obstacles": [
                      {"kind": "sphere", "centre": [40.0, 25.0], "radius": 8.0},
                      {"kind": "sphere", "centre": [40.0, -25.0], "radius": 8.0},
                      {"kind": "wall", "point": [0.0, -45.0], "normal": [0.0, 1.0]}]},
        "space": {"kind": "plane"},
        "initial": _start(150, [-80.0, -40.0], [0.0, 40.0]),
        "time": {"steps": 70000, "dt": 0.002},
        "recording": {"every": 5000, "arrays": ["position", "velocity"],
                      "observables_every": 100},
        "seed": 11,
    }
