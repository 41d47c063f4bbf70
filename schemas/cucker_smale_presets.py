"""Named Cucker–Smale runs. The 2007 paper proves its theorems without a simulation: the
preset is the setting of its Theorem 1 (beta = 0.25 < 1/2, K = sigma = 1), with N, the
initial box and speeds chosen here (docs/models/cucker_smale.md)."""

from __future__ import annotations

import math

from .presets import register_preset


@register_preset(
    "cucker-smale-2007",
    "Cucker-Smale 2007, Theorem 1: 100 agents, beta = 0.25 (unconditional flocking), "
    "K = sigma = lambda = 1, all-to-all; the velocity diameter decays to 0, t = 0..100.",
)
def cucker_smale_2007() -> dict:
    return {
        "name": "cucker-smale-2007",
        "model": {"kind": "cucker_smale", "K": 1.0, "sigma": 1.0, "beta": 0.25,
                  "coupling": 1.0, "normalization": "mean"},
        "space": {"kind": "plane"},
        "initial": {"kind": "random", "N": 100,
                    "region": {"kind": "box", "low": [-5.0, -5.0], "high": [5.0, 5.0]},
                    "heading_range": [-math.pi, math.pi], "speed_range": [0.0, 1.0]},
        "time": {"steps": 2000, "dt": 0.05},
        "recording": {"every": 100, "arrays": ["position", "velocity"],
                      "observables_every": 10},
        "seed": 7,
    }
