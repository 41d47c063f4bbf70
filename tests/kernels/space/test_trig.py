"""kernels/space/trig.py's cos_sin against numpy's cos and sin (libm) on [-pi, pi]: within
one ulp of libm's value, and (near the zeros of cos and sin, where that would need a third
part of pi/2) within 2^-60 absolute: what rotating a unit vector needs."""

import numpy as np
import pytest
import taichi as ti

from flocklab.kernels import runtime
from flocklab.kernels.space import trig


@pytest.mark.resets_taichi  # float32 re-initialises Taichi
@pytest.mark.parametrize("precision", ["float64", "float32"])
def test_cos_sin_within_one_ulp_of_libm(precision):
    runtime.ensure("cpu", 2, precision)
    dt = np.float32 if precision == "float32" else np.float64
    rng = np.random.default_rng(7)
    x = np.concatenate([
        rng.uniform(-np.pi, np.pi, 1_000_000),
        # the quadrant edges, both ends, zero and the tiny angles small eta gives
        np.pi / 4 * np.arange(-4, 5), np.nextafter(np.pi / 4 * np.arange(-3, 4), 10),
        np.nextafter(np.pi / 4 * np.arange(-3, 4), -10), [0.0, 1e-300, -1e-300, 1e-9],
    ]).astype(dt)
    x = np.clip(x, -np.pi, np.pi).astype(dt)
    out = ti.ndarray(float, shape=(x.size, 2))
    xs = ti.ndarray(float, shape=x.size)
    xs.from_numpy(x)

    @ti.kernel
    def eval_all(xs: ti.types.ndarray(), out: ti.types.ndarray()):
        for i in range(xs.shape[0]):
            cs = trig.cos_sin(xs[i])
            out[i, 0] = cs[0]
            out[i, 1] = cs[1]

    eval_all(xs, out)
    got = out.to_numpy()
    for k, ref in enumerate((np.cos(x), np.sin(x))):
        ulp = np.spacing(np.abs(ref).astype(dt))
        err = np.abs(got[:, k] - ref)
        near_zero = np.abs(ref) < 1e-3
        rel = err[~near_zero] / ulp[~near_zero]
        assert rel.max() <= 1.0, (k, float(rel.max()))
        assert err[near_zero].max(initial=0) <= np.finfo(dt).eps * 2**-8, k
    # sin(x) = x exactly where x is tiny; cos(0) = 1 exactly.
    assert got[-4, 0] == 1.0 and got[-4, 1] == 0.0
    assert got[-3, 1] == x[-3]
