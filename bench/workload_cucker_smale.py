"""Cucker–Smale benchmark workload: the cutoff model on the plane grid (all-to-all is
N^2 and capped at N = 10^4).

Agents on a jittered square lattice of spacing 1 with random velocities (speeds below 1),
cutoff 2 (about 12 partners within it and 36 candidates in the 3x3 cells, as the
flocking and Vicsek workloads), beta = 0.25, K = sigma = lambda = 1, mean normalisation,
semi-implicit Euler at dt = 0.01; observables every 10 steps (both diameters through the
streamed convex hulls).
"""


def cucker_smale_cutoff(n: int) -> dict:
    return {
        "name": f"bench-cucker-smale-cutoff-{n}",
        "model": {"kind": "cucker_smale", "beta": 0.25, "cutoff": 2.0},
        "space": {"kind": "plane"},
        "initial": {"kind": "random", "N": n, "speed_range": [0.0, 1.0],
                    "region": {"kind": "lattice", "spacing": 1.0, "jitter": 0.2}},
        "time": {"steps": 10, "dt": 0.01},
        "recording": {"observables_every": 10},
        "seed": 4,
    }


WORKLOADS = [("cucker_smale/cutoff", cucker_smale_cutoff)]
