"""Named M1 runs: Vicsek's 1995 setting and the JLM rules on a connected swarm."""

from __future__ import annotations

from .presets import register_preset

DEFAULT_PRESET = "vicsek-default"


@register_preset(DEFAULT_PRESET, "The embedded default (examples/vicsek.json): 10^5 Vicsek "
                 "agents, density 4, eta = 0.5, 200 steps.")
def vicsek_default() -> dict:
    return {
        "name": "vicsek-default",
        "model": {"kind": "vicsek", "rule": "vicsek", "v0": 0.03, "eta": 0.5},
        "space": {"kind": "periodic", "L": 158.11388300841898},
        "neighbours": {"radius": 1.0},
        "initial": {"kind": "random", "N": 100000},
        "time": {"steps": 200, "dt": 1.0},
        "recording": {"every": 50, "arrays": ["position", "heading"], "observables_every": 10},
        "seed": 42,
        "backend": "cpu",
    }


@register_preset("vicsek-1995", "Vicsek et al. 1995 (Fig. 1): N=300, L=7, r=1, v0=0.03, eta=2.")
def vicsek_1995() -> dict:
    return {
        "name": "vicsek-1995",
        "model": {"kind": "vicsek", "rule": "vicsek", "v0": 0.03, "eta": 2.0},
        "space": {"kind": "periodic", "L": 7.0},
        "neighbours": {"radius": 1.0},
        "initial": {"kind": "random", "N": 300},
        "time": {"steps": 500, "dt": 1.0},
        "recording": {"every": 10, "arrays": ["position", "heading"], "observables_every": 1},
        "seed": 1,
    }


@register_preset("jlm-leader", "JLM eq. 22: 30 followers and a leader (agent 0) in a 5x5 box.")
def jlm_leader() -> dict:
    return {
        "name": "jlm-leader",
        "model": {"kind": "vicsek", "rule": "leader", "v0": 0.01, "leader_heading": 0.5},
        "space": {"kind": "plane"},
        "neighbours": {"radius": 2.0},
        "initial": {"kind": "random", "N": 31, "region": {"kind": "box", "low": [0, 0],
                                                           "high": [5, 5]}},
        "time": {"steps": 300},
        "recording": {"every": 10, "arrays": ["position", "heading"]},
        "seed": 2,
    }


@register_preset("vicsek-3d", "examples/vicsek_3d.json: 10^5 Vicsek agents in the periodic "
                 "cube, density 4, r = 1, eta = 0.5 (spherical-cap noise), 200 steps.")
def vicsek_3d() -> dict:
    return {
        "name": "vicsek-3d",
        "model": {"kind": "vicsek", "rule": "vicsek", "v0": 0.03, "eta": 0.5},
        "space": {"kind": "periodic", "L": (100_000 / 4) ** (1 / 3), "dimension": 3},
        "neighbours": {"radius": 1.0},
        "initial": {"kind": "random", "N": 100000},
        "time": {"steps": 200, "dt": 1.0},
        "recording": {"every": 50, "arrays": ["position", "heading"], "observables_every": 10},
        "seed": 42,
        "backend": "cpu",
    }
