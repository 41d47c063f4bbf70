"""A GPU's grid build (blocked parallel scan, atomic scatter then per-bucket sort), built on
the CPU through the DevicePolicy, gives exactly the CPU's bucket starts and permutation."""

import numpy as np
import pytest
import taichi as ti

from flocklab.kernels.runtime import DevicePolicy
from flocklab.kernels.space.grid import Grid


def _build(pos: np.ndarray, r: float, L: float | None, serial: bool) -> Grid:
    grid = Grid(len(pos), r, L, DevicePolicy(serial_scatter=serial, dense_grid=serial))
    p = ti.ndarray(ti.f64, shape=pos.shape)
    p.from_numpy(pos)
    grid.build(p)
    return grid


@pytest.mark.parametrize(("n", "L"), [(1, 4.0), (700, 4.0), (5000, 30.0), (3000, None)])
def test_gpu_build_equals_cpu_build(taichi_cpu, n, L):
    rng = np.random.default_rng(n)
    pos = rng.uniform(0, L or 50.0, size=(n, 2))
    pos[: n // 3] = pos[0]  # one crowded bucket beside many empty ones
    cpu = _build(pos, 1.0, L, serial=True)
    gpu = _build(pos, 1.0, L, serial=False)
    # Bucket counts not a multiple of the scan's block: the last block is partial.
    start = cpu.start.to_numpy()
    assert np.array_equal(gpu.start.to_numpy(), start)
    assert start[-1] == n and (np.diff(start) >= 0).all()
    assert np.array_equal(gpu.perm.to_numpy(), cpu.perm.to_numpy())
