"""Named M2 and M3 runs: the simulations of papers 000 and 002.

Parameters the papers leave out are chosen here and documented in docs/models/flocking.md:
paper 000 gives N, the initial box and speeds, R and the duration but not the potential's
d, the graph's density, dt or the seed; paper 002 gives N = 5, the destination and the
shape of the obstacle only.
"""

from __future__ import annotations

import math

from .presets import register_preset

PAPER000_INITIAL = {
    "kind": "random",
    "N": 10,
    "region": {"kind": "box", "low": [-2.5, -2.5], "high": [2.5, 2.5]},
    "heading_range": [-math.pi, math.pi],
    "speed_range": [0.0, 1.0],
}


@register_preset(
    "tjp-fixed",
    "Paper 000, Fig. 4/7: 10 agents on a fixed random connected graph, 100 s.",
)
def tjp_fixed() -> dict:
    return {
        "name": "tjp-fixed",
        "model": {
            "kind": "flocking",
            "topology": "fixed",
            "graph": {"kind": "random_connected", "mean_degree": 4.0},
            "potential": {"kind": "log_barrier", "d": 1.0},
        },
        "space": {"kind": "plane"},
        "initial": PAPER000_INITIAL,
        "time": {"steps": 10_000, "dt": 0.01},
        "recording": {"every": 100, "arrays": ["position", "velocity"], "observables_every": 10},
        "seed": 11,
    }


@register_preset(
    "tjp-switching",
    "Paper 000, Fig. 5/6/8: 10 agents, switching topology |r_ij| < R = 2 m, 100 s.",
)
def tjp_switching() -> dict:
    return {
        "name": "tjp-switching",
        "model": {
            "kind": "flocking",
            "topology": "switching",
            "potential": {"kind": "log_barrier", "d": 1.0},
        },
        "space": {"kind": "plane"},
        "neighbours": {"radius": 2.0},
        "initial": PAPER000_INITIAL,
        "time": {"steps": 10_000, "dt": 0.01},
        "recording": {"every": 100, "arrays": ["position", "velocity"], "observables_every": 10},
        "seed": 11,
    }


def pi_obstacle(half_width: float, top: float, bottom: float, spacing: float) -> list[list[float]]:
    """Point obstacles every `spacing` along a Π: the bar y = top for |x| <= half_width and
    the legs x = +-half_width from y = top down to y = bottom (open at the bottom)."""
    nx = round(2 * half_width / spacing)
    ny = round((top - bottom) / spacing)
    bar = [[-half_width + k * 2 * half_width / nx, top] for k in range(nx + 1)]
    legs = [[s * half_width, top - k * (top - bottom) / ny] for s in (-1, 1)
            for k in range(1, ny + 1)]
    return [[round(x, 12), round(y, 12)] for x, y in bar + legs]


@register_preset(
    "tanner-obstacles",
    "Paper 002, section V: 5 vehicles from the south-west round the left leg of a Π of "
    "point obstacles to the destination (0, 0) inside it, 300 s.",
)
def tanner_obstacles() -> dict:
    return {
        "name": "tanner-obstacles",
        "model": {
            "kind": "flocking_obstacles",
            "potential": {"kind": "paper002"},
            "destination": [0.0, 0.0],
            "obstacles": pi_obstacle(half_width=2.5, top=2.5, bottom=-1.0, spacing=0.25),
            "obstacle_range": 0.5,
            "kappa": 1.0,
            "c_d": 0.5,
            "V_min": 0.6,
            "radius_every": 100,
            "radius_floor": 0.25,
            "stuck_speed": 1e-3,
        },
        "space": {"kind": "plane"},
        "neighbours": {"radius": 2.0},
        "initial": {
            "kind": "random",
            "N": 5,
            "region": {"kind": "disc", "center": [-4.5, -4.5], "radius": 1.5},
            "speed_range": [0.0, 0.5],
        },
        "time": {"steps": 15_000, "dt": 0.02},
        "recording": {"every": 100, "arrays": ["position", "velocity"], "observables_every": 10},
        "seed": 10,
    }


@register_preset(
    "tjp-switching-3d",
    "examples/flocking_3d.json: paper 000's switching law in 3D, 1000 agents from a "
    "jittered cubic lattice, R = 1.5, d = 1, 30 s.",
)
def tjp_switching_3d() -> dict:
    return {
        "name": "tjp-switching-3d",
        "model": {"kind": "flocking", "topology": "switching",
                  "potential": {"kind": "log_barrier", "d": 1.0}},
        "space": {"kind": "plane", "dimension": 3},
        # R = 1.5: the first shell of the lattice and part of the second. With R = 2 (the
        # 2D presets' radius) the interior agents' 30-odd neighbours press pairs to 0.1 d,
        # where the barrier's stiffness outruns any practical Euler step (dt = 0.002
        # still let Q rise and speeds reach 10^2): tests/schemas/test_presets_3d.py.
        "neighbours": {"radius": 1.5},
        "initial": {"kind": "random", "N": 1000, "speed_range": [0.0, 1.0],
                    "region": {"kind": "lattice", "low": [0.0, 0.0, 0.0], "spacing": 1.1,
                               "jitter": 0.2}},
        "time": {"steps": 3000, "dt": 0.01},
        "recording": {"every": 100, "arrays": ["position", "velocity"], "observables_every": 10},
        "seed": 1,
        "backend": "cpu",
    }
