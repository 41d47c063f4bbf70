"""The vicsek rule's by-cell step (grid.make_block_visitor: the agents of a cell share one
visit of their neighbour cells) against the per-agent step it replaces in the periodic box:
every agent's new position and heading bit for bit, in 2D and 3D, on the seams, with pairs
exactly at r, with crowded cells (blocks of four and a remainder), strict and inclusive,
either position update, with and without noise. The brute-force reference checks the
engine (which now takes the by-cell step) in tests/kernels/vicsek/test_vicsek.py and
test_vicsek_3d.py;
this file holds the two steps to the same bits, so that observing a run (the per-agent
visit, which also counts the graph) cannot change its trajectory."""

import itertools

import numpy as np
import pytest

from flocklab import kernels
from flocklab.kernels.model import kernel_for
from flocklab.kernels.models.vicsek.step import RULES, block_step_kernel, step_kernel
from flocklab.kernels.runtime import DevicePolicy
from flocklab.kernels.space import rng
from flocklab.schemas import Scenario
from tests.kernels.vicsek.test_vicsek import Frames

pytestmark = pytest.mark.usefixtures("taichi_cpu")


def lattice(dim: int, L: float, spacing: float) -> np.ndarray:
    """Points spacing apart from the origin: pairs exactly at r = spacing, and points on
    the cell edges and the seam (x = 0 is L away from x = L - spacing's neighbour)."""
    side = np.arange(0.0, L - 1e-9, spacing)
    return np.array(list(itertools.product(side, repeat=dim)))


def positions(layout: str, dim: int, L: float, n: int, r: float, gen) -> np.ndarray:
    if layout == "random":
        return gen.uniform(0.0, L, size=(n, dim))
    if layout == "ties":
        return lattice(dim, L, r)
    # crowded: most agents in two cells (one of them on the seam), the rest spread
    crowd = gen.uniform(0.0, 0.9 * r, size=(n, dim))
    crowd[: n // 3] += L - 0.95 * r
    crowd[n // 3: n // 2] = gen.uniform(0.0, L, size=(n // 2 - n // 3, dim))
    return crowd


def build(dim, L, r, pos, eta, inclusive, move, gen, noise="angular"):
    n = len(pos)
    directions = gen.normal(size=(n, dim))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    initial = {"kind": "explicit", "positions": pos.tolist()}
    if dim == 2:
        initial["headings"] = np.arctan2(directions[:, 1], directions[:, 0]).tolist()
    else:
        initial["velocities"] = directions.tolist()
    sc = Scenario.model_validate({
        "model": {"kind": "vicsek", "v0": 0.3, "eta": eta, "position_update": move,
                  "noise": noise},
        "space": {"kind": "periodic", "L": L, "dimension": dim},
        "neighbours": {"radius": r, "inclusive": inclusive},
        "initial": initial,
        "time": {"steps": 1, "dt": 1.0},
        "seed": 5,
    })
    rt = kernels.runtime.ensure("cpu")
    return kernel_for("vicsek")(sc, rt.policy)


def one_step(k, kernel) -> list[np.ndarray]:
    st = k.state
    kernel(st["pos"], k._theta(st.cur), st["ew"], st.ids, st.scratch("pos"),
           k._theta(st.scratch_all()), st.scratch("ew"), k.prm, rng.step_key(5, 0, 0),
           rng.step_key(5, 1, 0), k.bad, k.graph.parent, k.graph.deg, *k.grid.view())
    return [st.scratch("pos").to_numpy().copy(), st.scratch("ew").to_numpy().copy()]


CASES = [
    # dim, L, layout, n, eta, inclusive, move
    (2, 3.5, "random", 200, 1.0, False, "old_heading"),  # 3 cells across: seams everywhere
    (2, 5.0, "ties", 0, 0.0, True, "old_heading"),
    (2, 5.0, "ties", 0, 0.7, False, "new_heading"),
    (2, 7.2, "crowded", 300, 2.0, True, "old_heading"),
    (3, 3.5, "random", 300, 1.0, False, "old_heading"),
    (3, 4.0, "ties", 0, 0.0, True, "new_heading"),
    (3, 4.0, "ties", 0, 0.9, False, "old_heading"),
    (3, 5.3, "crowded", 400, 6.0, False, "new_heading"),
]


@pytest.mark.slow_cases("3-3.5-random-300-1.0-False-old_heading",
                        "3-4.0-ties-0-0.0-True-new_heading",
                        "3-5.3-crowded-400-6.0-False-new_heading")
@pytest.mark.parametrize("case", CASES, ids=lambda c: "-".join(map(str, c)))
def test_by_cell_step_equals_the_per_agent_step_bit_for_bit(case):
    dim, L, layout, n, eta, inclusive, move = case
    r = 1.0
    gen = np.random.default_rng(len(layout) + 10 * dim + n)
    k = build(dim, L, r, positions(layout, dim, L, n, r, gen), eta, inclusive, move, gen)
    assert k.grid.blocks and k.kernel is block_step_kernel(inclusive, move == "new_heading",
                                                           dim, False)
    k.state.sort(k.grid, 0)
    per_agent = step_kernel(RULES["vicsek"], inclusive, True, move == "new_heading", False,
                            dim, False)
    want = one_step(k, per_agent)
    got = one_step(k, k.kernel)
    for a, b in zip(want, got, strict=True):
        np.testing.assert_array_equal(a, b)
    # The case is not vacuous: agents have neighbours, some in blocks of more than one.
    counts = np.diff(k.grid.start.to_numpy())
    assert counts.max() > 1
    assert not np.array_equal(want[1], k.state["ew"].to_numpy())


def test_fewer_than_three_cells_across_keep_the_per_agent_step():
    gen = np.random.default_rng(1)
    k = build(3, 2.5, 1.0, gen.uniform(0, 2.5, size=(50, 3)), 0.5, False, "old_heading", gen)
    assert not k.grid.blocks
    assert k.kernel is step_kernel(RULES["vicsek"], False, True, False, False, 3, False)


def random_box(dim, L, n, eta, steps, seed, recording=None) -> Scenario:
    """N agents at random in the periodic box of side L, r = 1, v0 = 0.3."""
    return Scenario.model_validate({
        "model": {"kind": "vicsek", "v0": 0.3, "eta": eta},
        "space": {"kind": "periodic", "L": L, "dimension": dim},
        "neighbours": {"radius": 1.0},
        "initial": {"kind": "random", "N": n},
        "time": {"steps": steps, "dt": 1.0},
        "recording": recording or {},
        "seed": seed,
    })


@pytest.mark.slow_cases("3")
@pytest.mark.parametrize("dim", [2, 3])
def test_observing_every_step_leaves_the_trajectory_unchanged(dim):
    """Observed steps take the per-agent visit (with the graph), the others the by-cell
    one: a run observed every step ends on the bits of a run observed only at its ends."""
    finals = []
    for every in (1, 30):
        sc = random_box(dim, 6.0, 2000, eta=1.5, steps=30, seed=3,
                        recording={"every": 30, "observables_every": every,
                                   "arrays": ["position", "heading"]})
        sink = Frames()
        res = kernels.run(sc, sink=sink, path="per_step")
        assert res.status == "completed", res.error
        assert res.extra["engine_path"] == "per_step"
        assert len(res.observables["step"]) == (31 if every == 1 else 2)
        assert sink.steps[-1] == 30
        finals.append((sink.pos[-1], sink.theta[-1]))
    for a, b in zip(*finals, strict=True):
        np.testing.assert_array_equal(a, b)
    assert not np.array_equal(finals[0][0], sink.pos[0])  # the agents moved


@pytest.mark.parametrize("dim", [2, 3])
def test_a_gpu_policy_steps_per_agent_to_the_same_bits(dim):
    """A GPU keeps a thread per agent (DevicePolicy.cell_blocks False), built here on the
    CPU with the GPU's policy (its parallel scatter too): the trajectory's bits are the
    CPU policy's."""
    sc = random_box(dim, 7.0, 3000, eta=1.0, steps=10, seed=8)
    kernels.runtime.ensure("cpu")
    states = []
    for backend in ("cpu", "cuda"):
        k = kernel_for("vicsek")(sc, DevicePolicy.for_backend(backend))
        blocked = k.kernel is block_step_kernel(sc.inclusive, False, dim, False)
        assert blocked == (backend == "cpu")
        for step in range(10):
            k.step(step)
        states.append(k.frame(["position", "heading"]))
    for name in states[0]:
        np.testing.assert_array_equal(states[0][name], states[1][name])
