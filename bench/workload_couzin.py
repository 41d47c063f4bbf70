"""Couzin benchmark workloads: the zone model on the plane grid at any N.

2D: agents on a jittered square lattice of spacing 1 with random headings, zones r_r =
0.5, r_o = 1.25, r_a = 2 (cells of side 2: about 12 partners within r_a and 36 candidates
in the 3x3 cells, as the Vicsek, flocking and Cucker-Smale workloads), the paper's
field of view (270 degrees), turning rate (40 degrees/s), speed 3, sigma = 0.05, tau =
0.1 s. 3D: the same zones on a cubic lattice of spacing 1.5 (about 10 partners within
r_a, 64 candidates in the 27 cells). Observables every 10 steps.
"""


def _couzin(n: int, dim: int, spacing: float) -> dict:
    return {
        "name": f"bench-couzin-{dim}d-{n}",
        "model": {"kind": "couzin", "r_r": 0.5, "dr_o": 0.75, "dr_a": 0.75},
        "space": {"kind": "plane", "dimension": dim},
        "initial": {"kind": "random", "N": n,
                    "region": {"kind": "lattice", "low": [0.0] * dim, "spacing": spacing,
                               "jitter": 0.2}},
        "time": {"steps": 10, "dt": 0.1},
        "recording": {"observables_every": 10},
        "seed": 4,
    }


def couzin_2d(n: int) -> dict:
    return _couzin(n, 2, 1.0)


def couzin_3d(n: int) -> dict:
    return _couzin(n, 3, 1.5)


WORKLOADS = [("couzin/2d", couzin_2d), ("couzin/3d", couzin_3d)]
