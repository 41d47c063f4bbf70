"""Named M4 runs: the three simulations of Xi–Abed (paper 003, Section 4), and a 3D F1 run.

Every parameter the paper leaves out is chosen here and listed in docs/models/formation.md:
initial area [0, 50]^2, the gains k and k_g, the formations, the leader's timing, dt.
"""

from __future__ import annotations

import math

from .presets import register_preset

_AREA = {"kind": "box", "low": [0.0, 0.0], "high": [50.0, 50.0]}


@register_preset(
    "xi-abed-sim1",
    "Xi-Abed Simulation 1 (Figs. 4-5): F1, N=6, d=20, linear f, a wedge rotating by 90 deg "
    "over [8, 12] s, leader on a straight line to (-40, -30), still from t = 20 s.",
)
def sim1() -> dict:
    return {
        "name": "xi-abed-sim1",
        "model": {
            "kind": "formation",
            "design": "F1",
            "attraction": {"kind": "linear", "k": 1.0},
            "repulsion": {"kind": "inverse", "k_g": 100.0},
            "path": {"kind": "straight", "target": [-40.0, -30.0], "arrival_time": 20.0},
            "formation": {"kind": "named", "shape": "wedge"},
            "schedule": [{"start": 8.0, "end": 12.0, "rotate": math.pi / 2}],
        },
        "space": {"kind": "plane"},
        "neighbours": {"radius": 20.0},
        "initial": {"kind": "random", "N": 6, "region": _AREA},
        "time": {"steps": 3000, "dt": 0.01},
        "recording": {"every": 10, "arrays": ["position", "velocity"], "observables_every": 10},
        "seed": 1,
    }


@register_preset(
    "xi-abed-sim2",
    "Xi-Abed Simulation 2 (Figs. 6-7): F1, N=6, f(s) = 0.02 (s^2 + s), a hexagon (circle "
    "of 6) following a spline through three waypoints for 50 s.",
)
def sim2() -> dict:
    return {
        "name": "xi-abed-sim2",
        "model": {
            "kind": "formation",
            "design": "F1",
            "attraction": {"kind": "quadratic", "c": 0.02},
            "repulsion": {"kind": "inverse", "k_g": 100.0},
            "path": {
                "kind": "spline",
                "waypoints": [[0.0, 60.0], [-50.0, 50.0], [-70.0, 0.0]],
                "arrival_time": 60.0,
            },
            "formation": {"kind": "named", "shape": "circle"},
        },
        "space": {"kind": "plane"},
        "neighbours": {"radius": 20.0},
        "initial": {"kind": "random", "N": 6, "region": _AREA},
        "time": {"steps": 5000, "dt": 0.01},
        "recording": {"every": 10, "arrays": ["position", "velocity"], "observables_every": 10},
        "seed": 2,
    }


@register_preset(
    "xi-abed-sim3",
    "Xi-Abed Simulation 3 (Fig. 8): F2, N=100, one virtual leader on a straight line to "
    "(-40, -40), still from t = 20 s; the group settles in an F2 formation (D1-D3).",
)
def sim3() -> dict:
    return {
        "name": "xi-abed-sim3",
        "model": {
            "kind": "formation",
            "design": "F2",
            "attraction": {"kind": "linear", "k": 1.0},
            "repulsion": {"kind": "inverse", "k_g": 100.0},
            "path": {"kind": "straight", "target": [-40.0, -40.0], "arrival_time": 20.0},
        },
        "space": {"kind": "plane"},
        "neighbours": {"radius": 20.0},
        "initial": {"kind": "random", "N": 100, "region": _AREA},
        "time": {"steps": 4000, "dt": 0.01},
        "recording": {"every": 20, "arrays": ["position", "velocity"], "observables_every": 20},
        "seed": 12,
    }


@register_preset(
    "xi-abed-f1-3d",
    "examples/formation_3d.json: F1 in 3D, N=32 on a Fibonacci-sphere shell (nearest pair "
    "d = 20 apart), leader on a spline through 3D waypoints (a climbing turn), the shell "
    "turned by 90 deg about the x axis over [8, 12] s, 35 s.",
)
def f1_3d() -> dict:
    return {
        "name": "xi-abed-f1-3d",
        "model": {
            "kind": "formation",
            "design": "F1",
            "attraction": {"kind": "linear", "k": 1.0},
            "repulsion": {"kind": "inverse", "k_g": 100.0},
            "path": {
                "kind": "spline",
                "waypoints": [[60.0, 25.0, 45.0], [25.0, 60.0, 65.0], [-10.0, 25.0, 85.0]],
                "arrival_time": 25.0,
            },
            "formation": {"kind": "named", "shape": "shell"},
            "schedule": [{"start": 8.0, "end": 12.0, "rotate": math.pi / 2,
                          "axis": [1.0, 0.0, 0.0]}],
        },
        "space": {"kind": "plane", "dimension": 3},
        "neighbours": {"radius": 20.0},
        "initial": {"kind": "random", "N": 32,
                    "region": {"kind": "box", "low": [0.0, 0.0, 0.0],
                               "high": [50.0, 50.0, 50.0]}},
        "time": {"steps": 3500, "dt": 0.01},
        "recording": {"every": 10, "arrays": ["position", "velocity"], "observables_every": 10},
        "seed": 1,
    }
