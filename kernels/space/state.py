"""Agent state kept in neighbour-grid order, with the agent ids that undo the order.

Each step the grid's stable permutation moves every per-agent array into bucket order
(double-buffered), so kernels read neighbours contiguously; `ids[k]` is the agent stored
in slot k. Outputs are always given back in agent-id order. `sort(grid, step)` does it at
most once per step: a step and the observation of the same state share one sort.
"""

from collections.abc import Collection, Mapping

import numpy as np
import taichi as ti

from ..checkpoint import put
from ..runtime import as_real
from .grid import Grid, vector_rows

nd = ti.types.ndarray()
_PER_LAUNCH = 4  # arrays (the ids among them) one launch of _permute moves


@ti.func
def _move(src: ti.template(), dst: ti.template(), i, j):
    """dst's slot j = src's slot i: an element (scalar or vector) or a row of (N, C)."""
    if ti.static(vector_rows(src) or len(src.shape) == 1):
        dst[j] = src[i]
    else:
        for c in range(src.shape[1]):
            dst[j, c] = src[i, c]


@ti.kernel
def _permute(perm: nd, a: nd, a_out: nd, b: nd, b_out: nd, c: nd, c_out: nd, d: nd,
             d_out: nd, m: ti.template()):
    # The first m of (a, b, c, d) in one pass over perm, which a launch per array read
    # once per array.
    for i in range(perm.shape[0]):
        j = perm[i]
        _move(a, a_out, i, j)
        if ti.static(m > 1):
            _move(b, b_out, i, j)
        if ti.static(m > 2):
            _move(c, c_out, i, j)
        if ti.static(m > 3):
            _move(d, d_out, i, j)


def permute_all(perm: ti.Ndarray, pairs: list[tuple[ti.Ndarray, ti.Ndarray]]) -> None:
    """dst's slot perm[i] = src's slot i for every (src, dst) pair: up to four arrays a
    launch."""
    for g in range(0, len(pairs), _PER_LAUNCH):
        group = pairs[g:g + _PER_LAUNCH]
        padded = group + [pairs[0]] * (_PER_LAUNCH - len(group))  # unused: untouched
        _permute(perm, *[x for pair in padded for x in pair], len(group))


class SortedState:
    """Named (N,) or (N, C) arrays of the runtime's float type plus `ids`, permuted
    together. The (N, C) arrays named in `vectors` are held as (N,) arrays of C-vectors
    (same bytes, same order): a kernel then reads a row with one vector load where an
    (N, C) array costs a load, with its index arithmetic, per component (`grid.row` reads
    either; to_numpy gives (N, C) for both)."""

    def __init__(self, arrays: dict[str, np.ndarray], vectors: Collection[str] = ()):
        self.n = len(next(iter(arrays.values())))
        self.cur: dict[str, ti.Ndarray] = {}
        self._buf: dict[str, ti.Ndarray] = {}
        for name, a in arrays.items():
            if name in vectors:
                self.cur[name] = ti.Vector.ndarray(a.shape[1], float, shape=a.shape[0])
                self._buf[name] = ti.Vector.ndarray(a.shape[1], float, shape=a.shape[0])
            else:
                self.cur[name] = ti.ndarray(float, shape=a.shape)
                self._buf[name] = ti.ndarray(float, shape=a.shape)
            self.cur[name].from_numpy(as_real(a))
        self.ids = ti.ndarray(ti.i32, shape=self.n)
        self.ids.from_numpy(np.arange(self.n, dtype=np.int32))
        self._ids_buf = ti.ndarray(ti.i32, shape=self.n)
        self._sorted_for = -1  # the step whose positions `cur` is in grid order for

    def sort(self, grid: Grid, step: int) -> None:
        """Bucket the positions "pos" of step `step` in `grid` and move every array into
        that order, unless this step's state is already sorted."""
        if self._sorted_for != step:
            grid.build(self.cur["pos"], step)
            self.resort(grid)
            self._sorted_for = step

    def forget_sort(self) -> None:
        """The arrays were moved into another grid's order (`resort`): the next `sort`
        rebuilds."""
        self._sorted_for = -1

    def __getitem__(self, name: str) -> ti.Ndarray:
        return self.cur[name]

    def resort(self, grid: Grid) -> None:
        """Move every array into the order of `grid.perm` (computed from `cur` positions):
        one launch for the ids and up to three arrays."""
        permute_all(grid.perm, [(self.ids, self._ids_buf)]
                    + [(a, self._buf[name]) for name, a in self.cur.items()])
        self.ids, self._ids_buf = self._ids_buf, self.ids
        for name in self.cur:
            self.cur[name], self._buf[name] = self._buf[name], self.cur[name]

    def scratch(self, name: str) -> ti.Ndarray:
        """The spare buffer of `name`: a kernel may write the next state there, then `swap`."""
        return self._buf[name]

    def scratch_all(self) -> dict[str, ti.Ndarray]:
        return self._buf

    def swap(self, name: str) -> None:
        self.cur[name], self._buf[name] = self._buf[name], self.cur[name]

    def save(self) -> dict[str, np.ndarray]:
        """The arrays in their storage order and the ids: the slot order is part of the
        state (the next sort is stable, so it starts from this order, and each
        neighbour sum runs in it)."""
        return {"ids": self.ids.to_numpy(), **{f"state/{k}": a.to_numpy()
                                                for k, a in self.cur.items()}}

    def load(self, state: Mapping[str, np.ndarray]) -> None:
        """Back from `save`'s arrays (same names and shapes); the next `sort` rebuilds."""
        put(self.ids, "ids", state["ids"])
        for k, a in self.cur.items():
            put(a, f"state/{k}", state[f"state/{k}"])
        self.forget_sort()

    def ids_numpy(self) -> np.ndarray:
        return self.ids.to_numpy()

    def in_id_order(self, name: str, ids: np.ndarray | None = None) -> np.ndarray:
        a = self.cur[name].to_numpy()
        out = np.empty_like(a)
        out[self.ids_numpy() if ids is None else ids] = a
        return out
