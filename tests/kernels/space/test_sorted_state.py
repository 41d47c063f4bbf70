"""The sorted state moves every array with the grid's permutation, whatever its layout, and
the periodic cell of a position is the floored one of the old code for every input."""

import numpy as np
import pytest
import taichi as ti

from flocklab.kernels.runtime import DevicePolicy
from flocklab.kernels.space.grid import Grid, periodic_cell, row, set_row
from flocklab.kernels.space.state import SortedState

nd = ti.types.ndarray()


def _arrays(n: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    # Five arrays and the ids: two launches of the one-pass permutation (four a launch).
    return {"pos": rng.uniform(0, 6.0, size=(n, 2)), "w": rng.normal(size=n),
            "v3": rng.normal(size=(n, 3)), "e": rng.normal(size=(n, 2)),
            "t": rng.normal(size=n)}


@pytest.mark.parametrize("vectors", [(), ("pos", "v3"), ("pos", "v3", "e")])
def test_resort_moves_every_array_with_the_grid(taichi_cpu, vectors):
    rng = np.random.default_rng(3)
    n = 500
    arrays = _arrays(n, rng)
    st = SortedState(arrays, vectors=vectors)
    grid = Grid(n, 0.7, 6.0, DevicePolicy(serial_scatter=True, dense_grid=True))
    for step in range(2):  # the second sort starts from the first's order
        st.sort(grid, step)
        ids = st.ids_numpy()
        assert sorted(ids) == list(range(n))
        # Slot k holds agent ids[k], in bucket order: the cells never decrease.
        cell = np.minimum((arrays["pos"][ids] / grid.gf[0]).astype(int), grid.nc - 1)
        flat = cell[:, 0] + grid.nc * cell[:, 1]
        assert (np.diff(flat) >= 0).all()
        for name, a in arrays.items():
            assert np.array_equal(st[name].to_numpy(), a[ids]), name
            assert np.array_equal(st.in_id_order(name), a), name
        arrays["pos"] = (arrays["pos"] + 1.7) % 6.0  # move, then sort again
        st["pos"].from_numpy(arrays["pos"][ids])


@ti.kernel
def _copy_rows(src: nd, dst: nd):
    for i in range(src.shape[0]):
        set_row(dst, i, 2.0 * row(src, i, 3))


def test_row_and_set_row_read_both_layouts(taichi_cpu):
    a = np.random.default_rng(4).normal(size=(40, 3))
    for make in (lambda: ti.ndarray(ti.f64, shape=(40, 3)),
                 lambda: ti.Vector.ndarray(3, ti.f64, shape=40)):
        src, dst = make(), make()
        src.from_numpy(a)
        _copy_rows(src, dst)
        assert np.array_equal(dst.to_numpy(), 2.0 * a)


@ti.kernel
def _cells(x: nd, out: nd, gf: nd, nc: ti.i32):
    for i in range(x.shape[0]):
        c = periodic_cell(ti.math.vec2(x[i], -x[i]), gf, nc)
        out[i, 0] = c[0]
        out[i, 1] = c[1]


def test_periodic_cell_is_the_floored_modulo_for_any_input(taichi_cpu):
    """The branch that replaced "% nc" gives Python's floored modulo of min(floor(x / w),
    nc - 1), negative and far-out coordinates included."""
    L, nc = 10.0, 7
    w = L / nc
    x = np.array([0.0, 1e-300, 0.5, w, 3.3, L - 1e-12, L, 12.0, 70.0 + 1e-9,
                  -1e-300, -0.5, -w, -9.9, -10.0, -70.0, -1234.5])
    gf = ti.ndarray(ti.f64, shape=2)
    gf.from_numpy(np.array([w, L]))
    out = ti.ndarray(ti.i32, shape=(len(x), 2))
    xs = ti.ndarray(ti.f64, shape=len(x))
    xs.from_numpy(x)
    _cells(xs, out, gf, nc)
    inv = 1.0 / w
    want = [[min(int(np.floor(v * inv)), nc - 1) % nc for v in (u, -u)] for u in x]
    assert out.to_numpy().tolist() == want
    assert min(min(r) for r in want) == 0 and max(max(r) for r in want) == nc - 1
