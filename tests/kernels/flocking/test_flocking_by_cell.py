"""M2's and M3's kernels on the dense grid by cell blocks (kernels/space/blocks.py) against
the per-agent visit they replace: the same bits for every agent's step (euler) and control
(accel, the RK4 stages), in 2D and 3D, with the uniform radius and M3's per-agent radii
(rules own and min) and navigation, strict and inclusive, pairs exactly at R, and crowded
cells (blocks of four and a remainder; rows longer than the sieve's lists, and agents with
more neighbours than a list holds, so that the pair runs mid-row). The brute-force
references check the engine itself in tests/kernels/flocking/test_flocking_reference.py and
tests/kernels/flocking/test_flocking_3d.py."""

import numpy as np
import pytest

from flocklab import kernels
from flocklab.kernels.model import kernel_for
from flocklab.kernels.models.flocking.forces import grid_kernels
from flocklab.kernels.space.blocks import SIEVE_CAP
from flocklab.schemas import Scenario
from tests.kernels.flocking.test_flocking_reference import m2_scenario, m3_scenario

pytestmark = pytest.mark.usefixtures("taichi_cpu")


def m2_3d(n: int, spacing: float, inclusive: bool | None) -> Scenario:
    return Scenario.model_validate({
        "model": {"kind": "flocking", "topology": "switching", "neighbour_search": "grid",
                  "potential": {"kind": "log_barrier", "d": 1.0}},
        "space": {"kind": "plane", "dimension": 3},
        "neighbours": {"radius": 2.0, "inclusive": inclusive},
        "initial": {"kind": "random", "N": n, "speed_range": [0.0, 0.3],
                    "region": {"kind": "lattice", "low": [0.0, 0.0, 0.0],
                               "spacing": spacing, "jitter": 0.0 if spacing == 2.0 else 0.2}},
        "time": {"steps": 1, "dt": 0.01},
        "seed": 4,
    })


CASES = {
    "m2-2d": lambda: m2_scenario(n=500, search="grid"),
    "m2-2d-inclusive-ties": lambda: m2_scenario(n=400, search="grid", spacing=2.0,
                                                inclusive=True),
    "m2-2d-crowded": lambda: m2_scenario(n=600, search="grid", spacing=0.3),
    "m3-2d-own": lambda: m3_scenario(n=300, neighbour_search="grid"),
    "m3-2d-min": lambda: m3_scenario(n=300, neighbour_search="grid", radius_rule="min"),
    "m2-3d": lambda: m2_3d(1000, 1.0, None),
    "m2-3d-inclusive-ties": lambda: m2_3d(729, 2.0, True),
    "m2-3d-crowded": lambda: m2_3d(1000, 0.45, False),
}


def outputs(k, blocks: bool) -> list[np.ndarray]:
    euler, accel = grid_kernels(**k.flags, search=k.search(k.grid), dim=k.dim, blocks=blocks)
    st = k.state
    grids = (*k.grid.view(), *k.mission.obstacles.view())
    euler(st["pos"], st["vel"], k._rad(), st.scratch("pos"), st.scratch("vel"), k.prm,
          k.mission.nav, k.bad, *grids)
    out = [st.scratch("pos").to_numpy().copy(), st.scratch("vel").to_numpy().copy()]
    accel(st["pos"], st["vel"], k._rad(), st.scratch("pos"), k.prm, k.mission.nav, k.bad,
          *grids)
    return [*out, st.scratch("pos").to_numpy().copy(), k.bad.to_numpy().copy()]


@pytest.mark.parametrize("case", CASES)
# Each case compiles its own kernels (a minute each here): the plain 2D and 3D and crowded
# cases stay fast; ties at the radius stay fast in vicsek/test_vicsek_by_cell.py and the
# grid tests, radius_rule "min" in test_flocking_reference.py. M3's by-cell kernels (30 s
# of CPU compiling, the fast lane's largest case) run with --all.
@pytest.mark.slow_cases("m2-2d-inclusive-ties", "m2-3d-inclusive-ties", "m3-2d-min", "m3-2d-own",
                        "m2-2d", "m2-3d", "m2-3d-crowded")
def test_by_cell_kernels_equal_the_per_agent_ones_bit_for_bit(case):
    sc = CASES[case]()
    rt = kernels.runtime.ensure("cpu")
    k = kernel_for(sc.model.kind)(sc, rt.policy)
    k.step(0)  # M3: radii that differ between agents
    k._sort(1)
    assert k.grid.layout == "dense"
    k.bad.fill(0)
    want = outputs(k, blocks=False)
    k.bad.fill(0)
    got = outputs(k, blocks=True)
    for a, b in zip(want, got, strict=True):
        np.testing.assert_array_equal(a, b)
    assert want[3][0] == 0  # finite: the comparison is of numbers
    # Not vacuous: the control is not zero, and some cells hold more than one agent.
    assert np.abs(want[2]).max() > 0
    assert np.diff(k.grid.view()[0].to_numpy()[: k.grid.n_buckets + 1]).max() > 1
    if "crowded" in case:  # the lists fill: the pair runs before a row is through
        pos = k.state["pos"].to_numpy()
        d2 = ((pos[:, None, :] - pos[None, :, :]) ** 2).sum(-1)
        assert (d2 < sc.neighbours.radius**2).sum(1).max() > 2 * SIEVE_CAP
