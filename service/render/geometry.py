"""What a model draws besides its agents, as its card names them (`overlays`): the
interaction edges, obstacles and a destination, the virtual leader with its path and each
agent's virtual leader, marked agents.

All of it is read from the run folder (`RunData.drawing`): the worker wrote the engine's
own fixed graph and leader geometry there, so the picture shows exactly what the run used
and drawing never imports the engine. The metric graph is searched here, from the
recorded positions, and below `BRUTE_FORCE_MAX` agents without scipy (whose import costs
more than the search), so a snapshot starts in a fraction of a second.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..h5md import MAX_STORED_EDGES
from .errors import RenderInputError
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

    A fixed graph (M2's topology fixed): the one the run wrote down. Otherwise the metric
    graph of `neighbours` with the test in force (the paper's inclusive or strict one): for
    M3 at the initial radius R (the per-agent radii are not recorded; the summary's
    `adaptive_radius.halvings` says whether any changed), for M4 the repulsion graph
    |r_ij| < d.
    """
    drawing = run.drawing
    if "graph_edges" in drawing.arrays:
        return drawing.arrays["graph_edges"].astype(np.int64)
    if drawing.graph_edges_left_out:
        raise RenderInputError(
            f"this run's fixed graph has {drawing.graph_edges_left_out} edges, more than "
            f"a run folder keeps ({MAX_STORED_EDGES}): draw it without edges", loc="edges")
    if run.radius is None:
        return None
    return metric_edges(pos, run.radius, run.inclusive, run.box)


@dataclass
class Obstacles:
    points: np.ndarray  # (P, dim)
    discs: list[tuple[tuple[float, ...], float]]  # (centre, radius): spheres in 3D
    destination: tuple[float, ...]


def obstacles(run: RunData) -> Obstacles | None:
    d = run.drawing
    if not d.has("obstacles", "destination"):
        return None
    dim, empty = run.dimension, np.zeros(0)
    centres = np.asarray(d.arrays.get("disc_centres", empty), np.float64).reshape(-1, dim)
    radii = np.asarray(d.arrays.get("disc_radii", empty), np.float64)
    return Obstacles(
        np.asarray(d.arrays.get("obstacle_points", empty), np.float64).reshape(-1, dim),
        [(tuple(c), float(r)) for c, r in zip(centres, radii, strict=True)],
        tuple(np.asarray(d.arrays["destination"], np.float64)))


@dataclass
class Marked:
    """Agents ringed where they are, with one label (JLM's leader, agent 0)."""

    agents: np.ndarray  # (M,) agent ids
    label: str


def marked(run: RunData) -> Marked | None:
    d = run.drawing
    if not d.has("marked", "marked"):
        return None
    return Marked(np.asarray(d.arrays["marked"], np.int64).reshape(-1),
                  d.labels.get("marked_label", "marked"))


@dataclass
class Leaders:
    """M4's virtual leader p(t), its whole path, and (F1) each agent's r_id = p + b_i."""

    leader: np.ndarray  # (dim,)
    path: np.ndarray  # (K, dim) samples of p over the run
    targets: np.ndarray | None  # (N, dim) r_id(t) for F1, None for F2


def leaders(run: RunData, k: int) -> Leaders | None:
    """The leader and (F1) the virtual leaders at frame k: r_id = p + b_i, with
    b_i = sum_s offsets[s, i] @ offset_weights[k, s].T (the offset schedule's blend of
    its stored formations at that time, kernels/overlays.py)."""
    d = run.drawing
    if not d.has("leaders", "leader", "leader_path"):
        return None
    p = d.arrays["leader"][k]
    targets = None
    if "offsets" in d.arrays and "offset_weights" in d.arrays:
        w = d.arrays["offset_weights"][k]
        targets = p[None, :] + np.einsum("sni,sji->nj", d.arrays["offsets"], w)
    return Leaders(p, d.arrays["leader_path"], targets)
