"""Host observables over device arrays in blocks of rows, with numpy's whole-array bits.

The observables reduce N agents on the host in float64. A full host copy of an (N, 3)
state array and numpy's temporaries on it cost more at N = 10^6 than the device state
itself, so the rows come over a block at a time (`Rows`), and each reduction is the one
numpy computes on the whole array, bit for bit:
- numpy sums a 1-D array (a column or a flattened (N, C) array alike) pairwise: it cuts
  the length n at n2 = n/2 rounded down to a multiple of 8, recursively, down to pieces of
  at most 128 values (numpy's PW_BLOCKSIZE) summed with 8 partial sums. `PairwiseSum`
  cuts its stream where that recursion does, down to leaves of at most LEAF values, sums
  each leaf with numpy itself (whose recursion on the leaf is the whole array's below
  that cut) and adds the leaf sums up the same tree.
- numpy sums an (N, C) array over axis 0 row after row: `RowSum` carries the running
  row from block to block.
- min, max and the first index of the minimum combine across blocks exactly.
tests/kernels/space/test_stream.py checks each against numpy on the whole array.
"""

import numpy as np
import taichi as ti

nd = ti.types.ndarray()
LEAF = 1 << 16  # values per pairwise-sum leaf (a power of two >= numpy's 128)
BLOCK = 1 << 16  # rows per block read from the device
_NUMPY = {ti.f64: np.float64, ti.f32: np.float32, ti.i32: np.int32, ti.i64: np.int64}


def _split(n: int) -> int:
    """Where numpy's pairwise sum cuts n values: n/2 rounded down to a multiple of 8."""
    half = n // 2
    return half - half % 8


def leaf_lengths(n: int, leaf: int = LEAF) -> list[int]:
    """The lengths of the tree's leaves, in order (they add up to n)."""
    if n <= leaf:
        return [n]
    h = _split(n)
    return leaf_lengths(h, leaf) + leaf_lengths(n - h, leaf)


class PairwiseSum:
    """numpy's float64 `a.sum()` of `n` values that arrive in order, in pieces of any
    length (`add`), bit for bit: `total()` once all n have arrived."""

    def __init__(self, n: int, leaf: int = LEAF):
        self.n, self.leaf = n, leaf
        self._lengths = iter(leaf_lengths(n, leaf))
        self._want = next(self._lengths)
        self._buf = np.empty(min(n, leaf))
        self._have = 0
        self._sums: list[float] = []

    def add(self, values: np.ndarray) -> None:
        """The next values of the stream (any shape: taken flattened, C order)."""
        v = np.ravel(values)
        while v.size:
            take = min(v.size, self._want - self._have)
            self._buf[self._have:self._have + take] = v[:take]
            self._have += take
            v = v[take:]
            if self._have == self._want:
                self._sums.append(float(np.add.reduce(self._buf[:self._want])))
                self._have = 0
                self._want = next(self._lengths, 0)

    def total(self) -> float:
        if self.n == 0:
            return 0.0
        if len(self._sums) != len(leaf_lengths(self.n, self.leaf)) or self._have:
            raise ValueError("PairwiseSum.total before all values arrived")
        sums = iter(self._sums)

        def tree(n: int) -> float:
            if n <= self.leaf:
                return next(sums)
            h = _split(n)
            return tree(h) + tree(n - h)  # left before right, as numpy adds them

        return tree(self.n)


class RowSum:
    """numpy's `a.sum(axis=0)` of an (N, C) array whose rows arrive in blocks: the rows
    added one after another to the first."""

    def __init__(self) -> None:
        self.acc: np.ndarray | None = None

    def add(self, rows: np.ndarray) -> None:
        if len(rows):
            self.acc = (rows.sum(axis=0) if self.acc is None
                        else np.add.reduce(np.vstack([self.acc[None, :], rows]), axis=0))

    def total(self) -> np.ndarray:
        if self.acc is None:
            raise ValueError("RowSum.total of no rows")
        return self.acc


class ArgMin:
    """The value and first index of the minimum (np.argmin's: the first NaN if any) of a
    stream of 1-D blocks."""

    def __init__(self) -> None:
        self.value = np.nan
        self.index = -1
        self._seen = 0

    def add(self, block: np.ndarray) -> None:
        if len(block):
            k = int(np.argmin(block))
            v = block[k]
            if self.index < 0 or (not np.isnan(self.value) and (np.isnan(v) or v < self.value)):
                self.value, self.index = v, self._seen + k
        self._seen += len(block)


@ti.kernel
def _copy_rows(src: nd, dst: nd, lo: ti.i32):
    for k, c in ti.ndrange(dst.shape[0], dst.shape[1]):
        dst[k, c] = src[lo + k, c]


@ti.kernel
def _copy_items(src: nd, dst: nd, lo: ti.i32):
    for k in range(dst.shape[0]):
        dst[k] = src[lo + k]


@ti.kernel
def _take_rows(src: nd, index: nd, dst: nd):
    for k, c in ti.ndrange(dst.shape[0], dst.shape[1]):
        dst[k, c] = src[index[k], c]


class Rows:
    """Rows lo..hi of a device array (N,) or (N, C) as a numpy array of its type, read into
    one reused buffer of `block` rows (the view is valid until the next read)."""

    def __init__(self, src: ti.Ndarray, block: int = BLOCK):
        self.src = src
        shape = (min(block, src.shape[0]), *src.shape[1:])
        self._buf = np.empty(shape, dtype=_NUMPY[src.dtype])

    def __call__(self, lo: int, hi: int) -> np.ndarray:
        out = self._buf[:hi - lo]
        (_copy_rows if out.ndim == 2 else _copy_items)(self.src, out, lo)
        return out

    def take(self, index: np.ndarray) -> np.ndarray:
        """Rows `index` (at most a block of them, int32) of an (N, C) array, like `__call__`."""
        out = self._buf[:len(index)]
        _take_rows(self.src, np.ascontiguousarray(index, dtype=np.int32), out)
        return out

    def wide(self, lo: int, hi: int) -> np.ndarray:
        """The rows in float64 (a float32 array's values exactly, as runtime.wide)."""
        return self(lo, hi).astype(np.float64, copy=False)


def blocks(n: int, block: int = BLOCK):
    """(lo, hi) row ranges covering 0..n in order."""
    for lo in range(0, n, block):
        yield lo, min(lo + block, n)
