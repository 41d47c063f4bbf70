"""kernels/space/stream.py: block-wise host reductions give numpy's whole-array bits."""

import numpy as np
import pytest

from flocklab.kernels.space.stream import (
    ArgMin,
    PairwiseSum,
    RowSum,
    blocks,
    leaf_lengths,
)


def _values(rng, shape):
    """Values over 30 orders of magnitude, both signs: every rounding shows."""
    return rng.standard_normal(shape) * 10.0 ** rng.uniform(-15, 15, shape)


def _feed(rng, total, add, values):
    """Feed `values` (flattened order) to `add` in pieces of random lengths."""
    k = 0
    while k < total:
        m = int(rng.integers(1, 5000)) if rng.random() < 0.8 else int(rng.integers(1, 9))
        add(values[k:k + m])
        k += m


@pytest.mark.parametrize("n", [0, 1, 7, 8, 9, 127, 128, 129, 1000, 8193, 65536, 65537,
                               131079, 400_003])
@pytest.mark.parametrize("leaf", [128, 1024, 1 << 16])
def test_pairwise_sum_is_numpy_sum_bit_for_bit(n, leaf):
    rng = np.random.default_rng(n + leaf)
    a = _values(rng, n)
    s = PairwiseSum(n, leaf)
    _feed(rng, n, s.add, a)
    assert sum(leaf_lengths(n, leaf)) == n
    assert max(leaf_lengths(n, leaf)) <= max(leaf, n if n <= leaf else 0)
    assert np.float64(s.total()).tobytes() == np.float64(a.sum()).tobytes()


def test_pairwise_sum_of_a_column_and_of_a_flattened_array():
    """A strided column sums like a contiguous array; an (N, 3) array flattened in C order
    is one stream (kinetic energy: (v * v).sum())."""
    rng = np.random.default_rng(1)
    v = _values(rng, (300_001, 3))
    col = PairwiseSum(len(v))
    flat = PairwiseSum(v.size)
    for lo, hi in blocks(len(v), 70_000):
        col.add(v[lo:hi, 1])
        flat.add(v[lo:hi] * v[lo:hi])
    assert col.total() == v[:, 1].sum()
    assert flat.total() == (v * v).sum()


def test_pairwise_sum_refuses_a_total_before_the_end():
    s = PairwiseSum(10)
    s.add(np.ones(9))
    with pytest.raises(ValueError):
        s.total()


@pytest.mark.parametrize("cols", [2, 3])
def test_row_sum_is_numpy_axis0_sum(cols):
    rng = np.random.default_rng(cols)
    a = _values(rng, (250_007, cols))
    s = RowSum()
    for lo, hi in blocks(len(a), 65_536):
        s.add(a[lo:hi])
    assert s.total().tobytes() == a.sum(axis=0).tobytes()
    assert (s.total() / len(a)).tobytes() == a.mean(axis=0).tobytes()


@pytest.mark.parametrize("case", ["ties", "nan"])
def test_argmin_is_the_first_minimum(case):
    rng = np.random.default_rng(3)
    a = rng.integers(0, 50, 20_000).astype(np.float64)  # many ties at 0
    if case == "nan":
        a[[5000, 17000]] = np.nan
    m = ArgMin()
    for lo, hi in blocks(len(a), 999):
        m.add(a[lo:hi])
    assert m.index == np.argmin(a)
    assert np.array_equal(m.value, a[np.argmin(a)], equal_nan=True)


def test_rows_reads_device_blocks(taichi_cpu):
    import taichi as ti

    from flocklab.kernels.space.stream import Rows

    rng = np.random.default_rng(4)
    for shape, dtype, host in [((1000, 3), float, np.float64), ((1000,), ti.i32, np.int32)]:
        a = rng.uniform(-1, 1, shape).astype(host)
        dev = ti.ndarray(dtype, shape=shape)
        dev.from_numpy(a)
        rows = Rows(dev, block=300)
        got = np.concatenate([rows(lo, hi).copy() for lo, hi in blocks(1000, 300)])
        assert got.dtype == host and np.array_equal(got, a)
        if a.ndim == 2:
            pick = rng.integers(0, 1000, 300)
            assert np.array_equal(rows.take(pick), a[pick])
