"""Vicsek benchmark workload: density 4, r = 1, periodic 2D box, observables every 10 steps."""

import math


def vicsek(n: int) -> dict:
    return {
        "name": f"bench-vicsek-{n}",
        "model": {"kind": "vicsek", "rule": "vicsek", "v0": 0.03, "eta": 0.5,
                  "track_linked_intervals": False},
        "space": {"kind": "periodic", "L": math.sqrt(n / 4.0)},
        "neighbours": {"radius": 1.0},
        "initial": {"kind": "random", "N": n},
        "time": {"steps": 10},
        "recording": {"observables_every": 10},
        "seed": 1,
    }


WORKLOADS = [("vicsek/vicsek", vicsek)]
