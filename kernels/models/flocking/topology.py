"""Fixed interaction graphs (paper 000, section 4) as CSR adjacency in agent-id order.

Every generator is O(E log E) at worst, never O(N^2) (except `complete`, whose E is N^2):
  complete          all pairs
  ring, path        i ~ i + 1 (mod N for the ring)
  tree              b-ary: parent(i) = (i - 1) // b; random: parent(i) uniform in 0..i-1
                    (a random recursive tree), labels shuffled
  random_connected  a random recursive tree (connected by construction) plus uniformly
                    random extra pairs, without repeats, up to round(mean_degree N / 2) edges
  edges             the given list
Random graphs draw from numpy's PCG64 seeded with (seed, GRAPH_STREAM), a stream apart
from the initial state's, so the same seed gives the same graph.
"""

from __future__ import annotations

import numpy as np

from flocklab.schemas.flocking import GraphSpec

GRAPH_STREAM = 0x6772_6170  # "grap"


def build_edges(spec: GraphSpec, n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Undirected edges (u, v) with u < v, sorted, as two int64 arrays."""
    rng = np.random.default_rng([spec.seed if spec.seed is not None else seed, GRAPH_STREAM])
    i = np.arange(n, dtype=np.int64)
    if spec.kind == "complete":
        u, v = np.triu_indices(n, 1)
    elif spec.kind == "ring":
        u, v = (i, (i + 1) % n) if n >= 3 else (i[:-1], i[1:])
    elif spec.kind == "path":
        u, v = i[:-1], i[1:]
    elif spec.kind == "tree":
        if spec.branching is not None:
            u, v = (i[1:] - 1) // spec.branching, i[1:]
        else:
            u, v = _random_tree(n, rng)
    elif spec.kind == "random_connected":
        u, v = _random_connected(n, spec.n_edges(n), rng)
    else:
        e = np.asarray(spec.edges, dtype=np.int64).reshape(-1, 2)
        u, v = e[:, 0], e[:, 1]
    u, v = np.asarray(u, dtype=np.int64), np.asarray(v, dtype=np.int64)
    lo, hi = np.minimum(u, v), np.maximum(u, v)
    order = np.argsort(lo * n + hi, kind="stable")
    return lo[order], hi[order]


def _random_tree(n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A random recursive tree on shuffled labels: n - 1 edges, connected."""
    child = np.arange(1, n, dtype=np.int64)
    parent = np.floor(rng.random(n - 1) * child).astype(np.int64)
    label = rng.permutation(n).astype(np.int64)
    return label[parent], label[child]


def _random_connected(n: int, m: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A random spanning tree plus m - (n - 1) distinct uniformly random extra edges."""
    tu, tv = _random_tree(n, rng)
    tree_keys = np.minimum(tu, tv) * n + np.maximum(tu, tv)
    need = m - (n - 1)
    if need <= 0:
        return tu, tv
    if n * (n - 1) // 2 <= 4 * m:
        # Dense: choose among every pair that is not a tree edge.
        a, b = np.triu_indices(n, 1)
        pool = np.setdiff1d(a.astype(np.int64) * n + b, tree_keys, assume_unique=True)
        extra = rng.choice(pool, size=need, replace=False)
    else:
        # Sparse: sample pairs in batches, drop loops, repeats and tree edges (sort-based
        # set operations: numpy's hash-based unique is far slower at 10^7 keys).
        tree_sorted = np.sort(tree_keys)
        extra = np.empty(0, dtype=np.int64)
        while extra.size < need:
            k = int(1.2 * (need - extra.size)) + 64
            a = rng.integers(0, n, size=k, dtype=np.int64)
            b = rng.integers(0, n, size=k, dtype=np.int64)
            keys = np.concatenate([extra, (np.minimum(a, b) * n + np.maximum(a, b))[a != b]])
            keys.sort()
            keys = keys[np.r_[True, keys[1:] != keys[:-1]]]
            at = np.minimum(np.searchsorted(tree_sorted, keys), len(tree_sorted) - 1)
            extra = keys[tree_sorted[at] != keys]
        extra = rng.choice(extra, size=need, replace=False)
    return np.concatenate([tu, extra // n]), np.concatenate([tv, extra % n])


def to_csr(n: int, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(indptr, indices) as int32: agent i's neighbours are indices[indptr[i]:indptr[i+1]],
    in increasing id order (a fixed summation order)."""
    rows = np.concatenate([u, v])
    cols = np.concatenate([v, u])
    order = np.argsort(rows * n + cols, kind="stable")
    indptr = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(rows, minlength=n), out=indptr[1:])
    return indptr.astype(np.int32), cols[order].astype(np.int32)
