"""Olfati-Saber benchmark workload: Algorithm 2 at the paper's parameters (d = 7, r = 8.4,
eps = 0.1, h = 0.2, a = b = 5) on the plane grid.

Agents on a jittered square lattice of spacing 5 (about 9 neighbours within r and 25
candidates in the 3x3 cells of side r, as the flocking, Cucker-Smale and Vicsek
workloads' dozen) with random velocities (speeds below 1), a virtual leader at the
origin moving at (1, 0), c1^gamma = 0.02, c2^gamma = 0.3; semi-implicit Euler at
dt = 0.01; observables every 10 steps (the deviation energy's pass and the union-find of
every edge included).
"""


def olfati_saber_alg2(n: int) -> dict:
    return {
        "name": f"bench-olfati-saber-alg2-{n}",
        "model": {"kind": "olfati_saber", "algorithm": 2, "c1_gamma": 0.02, "c2_gamma": 0.3,
                  "leader": {"position": [0.0, 0.0], "velocity": [1.0, 0.0]}},
        "space": {"kind": "plane"},
        "initial": {"kind": "random", "N": n, "speed_range": [0.0, 1.0],
                    "region": {"kind": "lattice", "spacing": 5.0, "jitter": 0.2}},
        "time": {"steps": 10, "dt": 0.01},
        "recording": {"observables_every": 10},
        "seed": 4,
    }


WORKLOADS = [("olfati_saber/alg2", olfati_saber_alg2)]
