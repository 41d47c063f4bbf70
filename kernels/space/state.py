"""Agent state kept in neighbour-grid order, with the agent ids that undo the order.

Each step the grid's stable permutation moves every per-agent array into bucket order
(double-buffered), so kernels read neighbours contiguously; `ids[k]` is the agent stored
in slot k. Outputs are always given back in agent-id order. `sort(grid, step)` does it at
most once per step: a step and the observation of the same state share one sort.
"""

import numpy as np
import taichi as ti

from ..runtime import as_real
from .grid import Grid, permute, permute_rows


class SortedState:
    """Named (N,) or (N, C) arrays of the runtime's float type plus `ids`, permuted
    together."""

    def __init__(self, arrays: dict[str, np.ndarray]):
        self.n = len(next(iter(arrays.values())))
        self.cur: dict[str, ti.Ndarray] = {}
        self._buf: dict[str, ti.Ndarray] = {}
        for name, a in arrays.items():
            self.cur[name] = ti.ndarray(float, shape=a.shape)
            self.cur[name].from_numpy(as_real(a))
            self._buf[name] = ti.ndarray(float, shape=a.shape)
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
        """Move every array into the order of `grid.perm` (computed from `cur` positions)."""
        for name, a in self.cur.items():
            (permute_rows if len(a.shape) == 2 else permute)(a, self._buf[name], grid.perm)
            self.cur[name], self._buf[name] = self._buf[name], a
        permute(self.ids, self._ids_buf, grid.perm)
        self.ids, self._ids_buf = self._ids_buf, self.ids

    def scratch(self, name: str) -> ti.Ndarray:
        """The spare buffer of `name`: a kernel may write the next state there, then `swap`."""
        return self._buf[name]

    def scratch_all(self) -> dict[str, ti.Ndarray]:
        return self._buf

    def swap(self, name: str) -> None:
        self.cur[name], self._buf[name] = self._buf[name], self.cur[name]

    def ids_numpy(self) -> np.ndarray:
        return self.ids.to_numpy()

    def in_id_order(self, name: str, ids: np.ndarray | None = None) -> np.ndarray:
        a = self.cur[name].to_numpy()
        out = np.empty_like(a)
        out[self.ids_numpy() if ids is None else ids] = a
        return out
