"""Named Couzin 2002 runs: the four collective states of the paper's Fig. 1 (swarm, torus,
dynamic parallel, highly parallel) at the parameters of its Table 1 (N = 100, r_r = 1,
alpha = 270 degrees, theta = 40 degrees per second, tau = 0.1 s, s = 3, sigma = 0.05),
Delta r_a = 14 and Delta r_o in each state's range, d_o and d_a averaged as unit vectors
(combine "unit": with the raw sums the dynamic parallel group is as polarised as the
highly parallel one; docs/models/couzin.md says how these were chosen and what each
reaches). 3D, as the paper; agents start at random in a ball of
radius 5 with directions uniform on the sphere."""

from __future__ import annotations

from .presets import register_preset

STATES = {  # name: (Delta r_o, what it shows)
    "swarm": (0.0, "a swarm: cohesive, low polarization and milling"),
    "torus": (2.0, "a torus: milling about an empty core (high m, low p)"),
    "dynamic-parallel": (4.0, "a dynamic parallel group (high p, low m)"),
    "parallel": (13.0, "a highly parallel group (p near 1)"),
}


def couzin_2002(state: str, dr_o: float) -> dict:
    return {
        "name": f"couzin-2002-{state}",
        "model": {"kind": "couzin", "r_r": 1.0, "dr_o": dr_o, "dr_a": 14.0,
                  "field_of_view": 270.0, "turning_rate": 40.0, "speed": 3.0,
                  "sigma": 0.05, "combine": "unit"},
        "space": {"kind": "plane", "dimension": 3},
        "initial": {"kind": "random", "N": 100,
                    "region": {"kind": "ball", "radius": 5.0}},
        "time": {"steps": 3000, "dt": 0.1},
        "recording": {"every": 100, "arrays": ["position", "velocity"],
                      "observables_every": 10},
        "seed": 2002,
    }


def _register(state: str, dr_o: float, words: str):
    @register_preset(f"couzin-2002-{state}",
                     f"Couzin et al. 2002, Fig. 1: 100 agents in 3D, Delta r_o = {dr_o:g}, "
                     f"Delta r_a = 14: {words}; t = 0..300 s.")
    def build() -> dict:
        return couzin_2002(state, dr_o)

    return build


couzin_2002_swarm, couzin_2002_torus, couzin_2002_dynamic_parallel, couzin_2002_parallel = (
    _register(state, dr_o, words) for state, (dr_o, words) in STATES.items())
