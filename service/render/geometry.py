"""What a model draws besides its agents: interaction edges, obstacles and destination
(M3), the virtual leaders, their path and the formation offsets (M4).

The fixed graphs and the formation offsets are rebuilt with the engine's own pure-numpy
helpers (`kernels.models.flocking.topology`, `kernels.models.formation`), so the picture
shows exactly what the run used. Importing them imports Taichi's Python module but never
initialises it; the service draws in a child process, so the API process still never
imports the engine. The metric graph needs neither the engine nor the validated scenario, and below
`BRUTE_FORCE_MAX` agents not even scipy (whose import costs more than the search), so a
Vicsek or switching-graph snapshot starts in a fraction of a second.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np

from .run_data import RunData

BRUTE_FORCE_MAX = 4096  # agents: numpy's sort and sweep; above, scipy's k-d tree
_CANDIDATES = 1 << 20  # candidate pairs tested at a time (a few tens of MiB)


def metric_edges(pos: np.ndarray, radius: float, inclusive: bool, box: float | None
                 ) -> np.ndarray:
    """(E, 2) agent pairs i < j within the radius (minimum image in a periodic box),
    sorted by (i, j); positions (N, 2) or (N, 3)."""
    if len(pos) <= BRUTE_FORCE_MAX:
        return _all_pairs(pos, radius, inclusive, box)
    from scipy.spatial import cKDTree

    tree = cKDTree(np.mod(pos, box), boxsize=box) if box is not None else cKDTree(pos)
    pairs = tree.query_pairs(radius, output_type="ndarray")
    if not inclusive and len(pairs):
        d = displacement(pos[pairs[:, 0]], pos[pairs[:, 1]], box)
        pairs = pairs[distance(d) < radius]
    pairs = pairs.reshape(-1, 2)
    return pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]


def _all_pairs(pos: np.ndarray, radius: float, inclusive: bool, box: float | None
               ) -> np.ndarray:
    """The pairs within the radius by sort and sweep: agents sorted by x, each tested
    only against those at most `radius` further along x (past the seam of a periodic box
    too), with the same exact test as every other pair search. At the papers' densities
    that is a few dozen candidates per agent instead of N."""
    n = len(pos)
    if n < 2:
        return np.zeros((0, 2), np.int64)
    x = pos[:, 0] if box is None else np.mod(pos[:, 0], box)
    order = np.argsort(x, kind="stable")
    xs = x[order]
    ids = order
    if box is not None:  # the sorted row continued one box further, past the seam
        xs = np.concatenate([xs, xs + box])
        ids = np.concatenate([order, order])
    # Padded so that rounding in x + radius never drops a pair the exact test keeps.
    reach = radius + 1e-9 * (radius + float(np.abs(xs).max()))
    first = np.arange(n)
    last = np.searchsorted(xs, xs[:n] + reach, side="right")  # candidates first+1 .. last-1
    last = np.minimum(last, first + n)  # never an agent against itself, one box on
    counts = np.maximum(last - first - 1, 0)
    found = []
    # Candidates in chunks of about _CANDIDATES (a swarm lined up along y has ~N^2 / 2).
    ends = np.cumsum(counts)
    cuts = np.searchsorted(ends, np.arange(_CANDIDATES, int(ends[-1]), _CANDIDATES))
    for lo, hi in zip(np.r_[0, cuts + 1], np.r_[cuts + 1, n], strict=True):
        c = counts[lo:hi]
        i = np.repeat(first[lo:hi], c)
        j = i + 1 + np.arange(len(i)) - np.repeat(np.cumsum(c) - c, c)
        a, b = order[i], ids[j]
        d = displacement(pos[a], pos[b], box)
        dist = distance(d)
        near = dist <= radius if inclusive else dist < radius
        a, b = a[near].astype(np.int64), b[near].astype(np.int64)
        found.append(np.minimum(a, b) * n + np.maximum(a, b))
    # Sorted by (i, j); a box under two radii wide meets some pairs both ways round.
    keys = np.unique(np.concatenate(found))
    return np.column_stack([keys // n, keys % n])


def displacement(a: np.ndarray, b: np.ndarray, box: float | None) -> np.ndarray:
    """b - a, by the minimum image in a periodic box."""
    d = b - a
    if box is not None:
        d -= box * np.round(d / box)
    return d


def distance(d: np.ndarray) -> np.ndarray:
    """|d| of (K, dim) displacements (np.hypot in the plane, as the 2D tests count)."""
    if d.shape[1] == 2:
        return np.hypot(d[:, 0], d[:, 1])
    return np.sqrt((d * d).sum(axis=1))


def interaction_edges(run: RunData, pos: np.ndarray) -> np.ndarray | None:
    """The graph the model used at this frame, or None when it has none to draw.

    Vicsek and switching flocking: the metric graph of `neighbours` (the paper's
    inclusive or strict test). Fixed flocking: the run's fixed graph. Obstacles: the metric
    graph at the initial radius R (the per-agent radii are not recorded; the summary's
    `adaptive_radius.halvings` says whether any changed). Formation: the repulsion graph
    |r_ij| < d.
    """
    if run.kind == "flocking" and run.doc["model"].get("topology") == "fixed":
        model = run.scenario.model
        from flocklab.kernels.models.flocking.topology import build_edges

        u, v = build_edges(model.graph, run.n_agents, run.scenario.seed)
        return np.column_stack([u, v]).astype(np.int64)
    if run.radius is None:
        return None
    return metric_edges(pos, run.radius, run.inclusive, run.box)


@dataclass
class Obstacles:
    points: np.ndarray  # (P, dim)
    discs: list[tuple[tuple[float, ...], float]]  # (centre, radius): spheres in 3D
    destination: tuple[float, ...]


def obstacles(run: RunData) -> Obstacles | None:
    if run.kind != "flocking_obstacles":
        return None
    model = run.scenario.model
    return Obstacles(np.asarray(model.obstacles, dtype=np.float64).reshape(-1, run.dimension),
                     [(tuple(d.center), d.radius) for d in model.discs],
                     tuple(model.destination))


@dataclass
class Leaders:
    """M4's virtual leader p(t), its whole path, and (F1) each agent's r_id = p + b_i."""

    leader: np.ndarray  # (dim,)
    path: np.ndarray  # (K, dim) samples of p over the run
    targets: np.ndarray | None  # (N, dim) r_id(t) for F1, None for F2


def leaders(run: RunData, t: float) -> Leaders | None:
    if run.kind != "formation":
        return None
    path, samples, schedule = _leader_motion(run)
    p = path.position(t)
    targets = p[None, :] + schedule.at(t) if schedule is not None else None
    return Leaders(p, samples, targets)


@lru_cache(maxsize=4)
def _leader_motion(run: RunData) -> tuple[Any, np.ndarray, Any]:
    """The run's leader path p(t), 400 samples of it over the run, and (F1) its offset
    schedule b_i(t): built once per run, not per movie frame (sampling an arc-length
    spline is about half a second)."""
    model = run.scenario.model
    from flocklab.kernels.models.formation.path import make_path

    obs, dim = run.observables, run.dimension
    columns = [f"leader_{c}" for c in "xyz"[:dim]]
    if all(c in obs and len(obs[c]) for c in columns):
        start = np.array([obs[c][0] for c in columns])  # p(0) as the run had it
    else:
        start = run.frame(0).position.mean(axis=0)
    path = make_path(model.path, start)
    t_end = float(run.scenario.time.steps * run.scenario.time.dt)
    samples = np.array([path.position(s) for s in np.linspace(0.0, t_end, 400)])
    schedule = None
    if model.design == "F1":
        from flocklab.kernels.models.formation.schedule import OffsetSchedule

        d = float(run.scenario.neighbours.radius)
        schedule = OffsetSchedule(model.formation, model.schedule, run.n_agents, d, dim)
    return path, samples, schedule
