"""The fused Vicsek visit skips the cells of the 3x3 block that lie all farther than r
from an agent (`reach`). It may drop only pairs beyond r: agents exactly r apart, on cell
sides and far from the origin keep every neighbour."""

import numpy as np
import pytest

from flocklab import kernels
from flocklab.schemas import Scenario
from tests.reference import degrees


def lattice_run(L, inclusive, offset=0.0, jitter=0.0):
    """One observed step of 144+ agents on a lattice of spacing r / 2 (many pairs exactly
    r apart; cells of a 6-wide box are 1.2 wide, so agents sit at every offset from a
    cell side), plus random ones; the degrees of G(0) and the positions."""
    g = np.arange(12) * 0.5
    pos = np.stack(np.meshgrid(g, g), axis=-1).reshape(-1, 2)
    rand = np.random.default_rng(3).uniform(0.0, 6.0, size=(40, 2))
    pos = np.concatenate([pos, rand]) + offset
    if jitter:
        pos += np.random.default_rng(4).uniform(-jitter, jitter, size=pos.shape)
    sc = Scenario.model_validate({
        "model": {"kind": "vicsek", "v0": 0.01, "eta": 0.0},
        "space": {"kind": "periodic", "L": L} if L else {"kind": "plane"},
        "neighbours": {"radius": 1.0, "inclusive": inclusive},
        "initial": {"kind": "explicit", "positions": pos.tolist(),
                    "headings": np.linspace(-3, 3, len(pos)).tolist()},
        "time": {"steps": 1, "dt": 1.0},
        "recording": {"observables_every": 1},
        "seed": 1,
    })
    res = kernels.run(sc)
    assert res.extra["engine_path"] == "fused"
    return res.observables, pos


@pytest.mark.parametrize("inclusive", [True, False])
@pytest.mark.parametrize("L, offset", [(6.0, 0.0), (None, 0.0), (None, 1000.25)],
                         ids=["periodic", "plane", "plane-far"])
@pytest.mark.parametrize("jitter", [0.0, 1e-12])
def test_degrees_equal_brute_force_at_exactly_r(taichi_cpu, L, offset, inclusive, jitter):
    obs, pos = lattice_run(L, inclusive, offset, jitter)
    deg = degrees(pos, 1.0, L, inclusive)
    assert obs["degree_mean"][0] * len(pos) == deg.sum()
    assert (obs["degree_min"][0], obs["degree_max"][0]) == (deg.min(), deg.max())
    assert obs["isolated"][0] == np.count_nonzero(deg == 0)
