"""Independent brute-force numpy references of M2 (paper 000) and M3 (paper 002), and the
engine's step-by-step agreement with them at small N.

The references share no code with the engine: O(N^2) pair matrices, the potential's
derivative written as V'(s) = -2a/s^3 + 2/s, the navigation function's gradient by the
quotient rule with grad prod_o beta_o summed term by term (the engine folds a product rule),
and their own RK4.
"""

from __future__ import annotations

import numpy as np
import pytest

from flocklab import kernels
from flocklab.kernels.model import all_kernels
from flocklab.kernels.models.flocking.fused import FlockingBatch
from flocklab.kernels.runtime import DevicePolicy
from flocklab.schemas import Scenario

# Taichi on the CPU for every test (the two-path `path` fixture does not start it).
pytestmark = pytest.mark.usefixtures("taichi_cpu")

TOL = 1e-10


# --- references ---------------------------------------------------------------------------

def pair_geometry(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """d[i, j] = r_j - r_i and s2[i, j] = |r_ij|^2 (2 or 3 coordinates)."""
    d = x[None, :, :] - x[:, None, :]
    s2 = d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1]
    return d, s2 + d[..., 2] * d[..., 2] if x.shape[1] == 3 else s2


def potential_force(d: np.ndarray, s2: np.ndarray, mask: np.ndarray, a: float) -> np.ndarray:
    """sum_j -grad_{r_i} V(|r_ij|) over mask, V(s) = a/s^2 + ln s^2 + c."""
    s = np.sqrt(np.where(mask, s2, 1.0))
    dv = -2.0 * a / s**3 + 2.0 / s  # V'(s)
    f = np.where(mask, dv / s, 0.0)  # -V'(s) (r_i - r_j)/s = (V'(s)/s) (r_j - r_i)
    return (f[..., None] * d).sum(axis=1)


def alignment(v: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """-sum_{j in N_i} (v_i - v_j)."""
    return (mask[..., None] * (v[None, :, :] - v[:, None, :])).sum(axis=1)


def m2_accel(x, v, *, a, adj=None, R=None, inclusive=False):
    """u_i of eq. 3 (paper 000): fixed 0-1 adjacency `adj`, or switching |r_ij| < R with
    the potential saturated at R (eq. 10)."""
    d, s2 = pair_geometry(x)
    off = ~np.eye(len(x), dtype=bool)
    if adj is not None:
        return alignment(v, adj) + potential_force(d, s2, adj, a)
    near = (s2 <= R * R if inclusive else s2 < R * R) & off
    return alignment(v, near) + potential_force(d, s2, (s2 < R * R) & off, a)


def navigation_ref(x, dest, centers, radii, d, kappa):
    """V_i and grad V_i (paper 002, p. 3) for every agent, all obstacles, by brute force."""
    lam = (d * d + 1.0) / (d * d)
    V = np.empty(len(x))
    G = np.empty_like(x)
    for i, xi in enumerate(x):
        if len(centers):
            rel = xi - centers
            dist = np.hypot(rel[:, 0], rel[:, 1]) if x.shape[1] == 2 else np.sqrt(
                (rel * rel).sum(axis=1))
            delta = dist - radii
            m = delta**2 < d**2  # m = 1/2 (sign(d^2 - delta^2) + 1)
            e = delta - d
            beta = np.where(m, 1.0 - lam * e**2 / (e**2 + 1.0), 1.0)
            dbeta = np.where(m, -2.0 * lam * e / (e**2 + 1.0) ** 2, 0.0)
            gbeta = dbeta[:, None] * rel / dist[:, None]
            others = np.where(np.eye(len(beta), dtype=bool), 1.0, beta[None, :])
            B = np.prod(beta)
            gB = (np.prod(others, axis=1)[:, None] * gbeta).sum(axis=0)
        else:
            B, gB = 1.0, np.zeros(x.shape[1])
        y = xi - dest
        a = y @ y
        D = a**kappa + B
        gD = 2.0 * kappa * a ** (kappa - 1.0) * y + gB
        num, den = a, D ** (1.0 / kappa)
        V[i] = num / den
        # quotient rule: (grad num * den - num * grad den) / den^2
        G[i] = (2.0 * y * den - num * (1.0 / kappa) * D ** (1.0 / kappa - 1.0) * gD) / den**2
    return V, G


class M3Ref:
    """Paper 002's closed loop (eq. 3, eq. 4) for explicit parameters."""

    def __init__(self, p, R0: float, inclusive: bool):
        self.p = p
        self.a, _ = p.potential.coefficients()
        self.centers = np.array([*p.obstacles, *(c.center for c in p.discs)]).reshape(
            -1, len(p.destination))
        self.radii = np.array([0.0] * len(p.obstacles) + [c.radius for c in p.discs])
        self.inclusive = inclusive
        self.R0 = R0

    def nav(self, x):
        p = self.p
        return navigation_ref(x, np.array(p.destination), self.centers, self.radii,
                              p.obstacle_range, p.kappa)

    def pair_r(self, R):
        n = len(R)
        if self.p.radius_rule == "own":
            return np.repeat(R[:, None], n, axis=1)
        return np.minimum(R[:, None], R[None, :])

    def accel(self, x, v, R):
        p = self.p
        d, s2 = pair_geometry(x)
        off = ~np.eye(len(x), dtype=bool)
        r2 = self.pair_r(R) ** 2
        near = (s2 <= r2 if self.inclusive else s2 < r2) & off
        u = alignment(v, near) + potential_force(d, s2, (s2 < r2) & off, self.a)
        V, G = self.nav(x)
        u -= G
        region = {"above_vmin": V > p.V_min, "below_vmin": V <= p.V_min,
                  "everywhere": np.ones(len(x), dtype=bool)}[p.damping_region]
        return u - p.c_d * region[:, None] * v

    def radius(self, x, v, R):
        """Eq. 4, synchronously."""
        p = self.p
        V, _ = self.nav(x)
        stuck = ((v * v).sum(axis=1) < p.stuck_speed**2) & (V > p.V_min)
        _, s2 = pair_geometry(x)
        r2 = self.pair_r(R) ** 2
        near = (s2 <= r2 if self.inclusive else s2 < r2) & ~np.eye(len(x), dtype=bool)
        grown = np.max(np.where(near, R[None, :], R[:, None]), axis=1)
        return np.where(stuck, np.maximum(R / 2, p.radius_floor), np.maximum(R, grown))


def euler(x, v, u, dt):
    v = v + dt * u
    return x + dt * v, v


def rk4(x, v, accel, dt):
    k1x, k1v = v, accel(x, v)
    k2x, k2v = v + dt / 2 * k1v, accel(x + dt / 2 * k1x, v + dt / 2 * k1v)
    k3x, k3v = v + dt / 2 * k2v, accel(x + dt / 2 * k2x, v + dt / 2 * k2v)
    k4x, k4v = v + dt * k3v, accel(x + dt * k3x, v + dt * k3v)
    return (x + dt / 6 * (k1x + 2 * k2x + 2 * k3x + k4x),
            v + dt / 6 * (k1v + 2 * k2v + 2 * k3v + k4v))


# --- scenarios ----------------------------------------------------------------------------

def lattice(n: int, spacing: float, seed: int, jitter: float = 0.2, speed: float = 0.5,
            origin=(0.0, 0.0)) -> dict:
    """Explicit initial state: a jittered square lattice, random velocities."""
    rng = np.random.default_rng(seed)
    side = int(np.ceil(np.sqrt(n)))
    g = np.stack(np.meshgrid(np.arange(side), np.arange(side)), -1).reshape(-1, 2)[:n]
    pos = origin + spacing * (g + rng.uniform(-jitter, jitter, size=(n, 2)))
    vel = rng.uniform(-speed, speed, size=(n, 2))
    return {"kind": "explicit", "positions": pos.tolist(), "velocities": vel.tolist()}


def m2_scenario(topology="switching", n=20, steps=200, dt=0.01, integrator="semi_implicit_euler",
                graph=None, R=2.0, inclusive=None, seed=5, d=1.0, spacing=1.1,
                speed=0.5, search="auto") -> Scenario:
    """search: auto, all_pairs, grid (the dense plane grid here: compact swarms), or hash
    (the engine's hashed grid, forced by `make_kernel`)."""
    search = "grid" if search == "hash" else search
    model = {"kind": "flocking", "topology": topology, "integrator": integrator,
             "potential": {"kind": "log_barrier", "d": d}, "neighbour_search": search}
    spec = {"model": model, "space": {"kind": "plane"},
            "initial": lattice(n, spacing, seed, speed=speed),
            "time": {"steps": steps, "dt": dt}, "seed": seed}
    if topology == "fixed":
        model["graph"] = graph or {"kind": "random_connected", "mean_degree": 4.0}
    else:
        spec["neighbours"] = {"radius": R, "inclusive": inclusive}
    return Scenario.model_validate(spec)


def m3_scenario(n=12, steps=200, dt=0.01, R=2.0, seed=7, **model) -> Scenario:
    """As m2_scenario; model["neighbour_search"] = "hash" selects "grid" (see make_kernel)."""
    if model.get("neighbour_search") == "hash":
        model["neighbour_search"] = "grid"
    base = {
        "kind": "flocking_obstacles",
        "destination": [1.5, -3.0],
        "obstacles": [[0.4, -1.1], [1.6, -1.2], [2.5, -0.8], [1.0, -1.4]],
        "discs": [{"center": [3.4, -2.2], "radius": 0.6}],
        "obstacle_range": 0.6,
        "radius_every": 5,
        "stuck_speed": 0.1,
        "radius_floor": 1.0,
        "V_min": 0.3,
        "c_d": 2.0,
    }
    base.update(model)
    return Scenario.model_validate({
        "model": base, "space": {"kind": "plane"}, "neighbours": {"radius": R},
        "initial": lattice(n, 1.05, seed, speed=0.4, origin=(0.0, 0.0)),
        "time": {"steps": steps, "dt": dt}, "seed": seed,
    })


class FusedKernel:
    """The per-step kernel's test interface (step, observe, frame, extra, the radii) over a
    fused batch of one replica observed at every step."""

    def __init__(self, sc: Scenario):
        spec = sc.model_dump(mode="json")
        spec["recording"]["observables_every"] = 1
        self.batch = FlockingBatch([Scenario.model_validate(spec)])
        self.done = 0  # steps advanced
        self.state = self
        self.n = sc.n_agents
        self.indptr, self.indices = self.batch.args["ptr"], self.batch.args["idx"]  # fixed

    def step(self, step: int) -> None:
        assert step <= self.done, "steps in order"
        if step == self.done:
            self.batch.advance(step, step + 1)
            self.done = step + 1
        div = self.batch.divergence(0, self.batch.status())
        if div is not None:
            raise kernels.SimulationDiverged(*div)

    def observe(self, step: int) -> dict[str, float]:
        if step == self.done:  # X(step) is observed by the launch that steps it
            self.step(step)
        obs = self.batch.observables(0, self.batch.status())
        (row,) = np.nonzero(obs["step"] == step)[0]
        return {k: float(v[row]) for k, v in obs.items() if k != "step"}

    def frame(self, arrays: list[str]) -> dict[str, np.ndarray]:
        return self.batch.frame(0, arrays, self.done)

    def extra(self):
        return self.batch.extra(0, self.batch.status())

    def in_id_order(self, name: str) -> np.ndarray:
        assert name == "rad"
        return self.batch.args["rad"].to_numpy()


def fused_or_skip(path: str, sc: Scenario, variant: bool = False) -> None:
    """Skip the fused run of a per-step variant (M3's radius_rule min: the engine runs it
    per step; variant: the hashed grid, a per-step concept)."""
    if path == "fused" and (variant or kernels.engine.choose_path(sc, "cpu") == "per_step"):
        pytest.skip("a per-step path variant")


def make_kernel(sc: Scenario, hashed: bool = False, path: str = "per_step"):
    """The scenario's kernel; hashed: never use the dense plane grid (test the engine's).
    path "fused": the fused batch where the engine would take it (`FusedKernel`)."""
    if path == "fused" and kernels.engine.choose_path(sc, "cpu") == "fused":
        return FusedKernel(sc)
    # hashed: the policy of a device without the dense grid (a GPU's), on the CPU.
    policy = DevicePolicy(serial_scatter=True, dense_grid=not hashed)
    return all_kernels()[sc.model.kind](sc, policy)


def state(k) -> tuple[np.ndarray, np.ndarray]:
    f = k.frame(["position", "velocity"])
    return f["position"], f["velocity"]


def fixed_adjacency(k) -> np.ndarray:
    """The engine's fixed graph as a dense matrix (the generator is tested separately)."""
    indptr, indices = k.indptr.to_numpy(), k.indices.to_numpy()
    adj = np.zeros((k.n, k.n), dtype=bool)
    for i in range(k.n):
        adj[i, indices[indptr[i]:indptr[i + 1]]] = True
    return adj


# --- tests --------------------------------------------------------------------------------

M2_CASES = [
    dict(topology="fixed"),
    dict(topology="fixed", integrator="rk4", graph={"kind": "ring"}),
    dict(topology="fixed", graph={"kind": "tree", "branching": 3}, d=0.8),
    dict(topology="switching", search="grid"),
    dict(topology="switching", search="hash"),
    dict(topology="switching", search="all_pairs"),
    dict(topology="switching", integrator="rk4", inclusive=True, R=1.6, search="grid"),
    dict(topology="switching", integrator="rk4", inclusive=True, R=1.6, search="hash"),
    dict(topology="switching", integrator="rk4", inclusive=True, R=1.6, search="all_pairs"),
    dict(topology="switching", n=40, R=2.5, d=1.3, spacing=1.2, speed=1.0, search="grid"),
]


@pytest.mark.parametrize("case", M2_CASES, ids=lambda c: "-".join(f"{v}" for v in c.values()))
# Each case stays fast on one schedule (every search on each, fused RK4 once); --all runs
# both.
@pytest.mark.fast_cases("fused-fixed", "fused-fixed-{'kind': 'tree', 'branching': 3}-0.8",
                        "fused-switching-grid", "fused-switching-all_pairs",
                        "per_step-fixed-rk4-{'kind': 'ring'}", "fused-fixed-rk4-{'kind': 'ring'}",
                        "per_step-switching-hash", "per_step-switching-rk4-True-1.6-all_pairs",
                        "per_step-switching-40-2.5-1.3-1.2-1.0-grid")
def test_m2_matches_reference_step_by_step(path, case):
    sc = m2_scenario(**case)
    fused_or_skip(path, sc, case.get("search") == "hash")
    k = make_kernel(sc, hashed=case.get("search") == "hash", path=path)
    x, v = state(k)
    a, _ = sc.model.potential.coefficients()
    if sc.model.topology == "fixed":
        adj = fixed_adjacency(k)
        accel = lambda x, v: m2_accel(x, v, a=a, adj=adj)  # noqa: E731
    else:
        R = sc.neighbours.radius
        accel = lambda x, v: m2_accel(x, v, a=a, R=R, inclusive=sc.inclusive)  # noqa: E731
    dt = sc.time.dt
    worst = 0.0
    for step in range(sc.time.steps):
        k.step(step)
        if sc.model.integrator == "rk4":
            x, v = rk4(x, v, accel, dt)
        else:
            x, v = euler(x, v, accel(x, v), dt)
        kx, kv = state(k)
        worst = max(worst, np.abs(kx - x).max(), np.abs(kv - v).max())
        assert worst < TOL, f"step {step}: engine and reference differ by {worst:.3g}"
    assert np.abs(v).max() > 1e-3  # the run did something
    if case.get("search") in ("grid", "hash") and path == "per_step":
        assert k.grid.layout == {"grid": "dense", "hash": "hash"}[case["search"]]


M3_CASES = [
    dict(neighbour_search="grid"),
    dict(neighbour_search="hash"),
    dict(neighbour_search="all_pairs"),
    dict(radius_rule="min", damping_region="below_vmin", neighbour_search="grid"),
    dict(radius_rule="min", neighbour_search="hash"),
    dict(kappa=2.0, damping_region="everywhere"),
    dict(integrator="rk4", radius_every=3, neighbour_search="grid"),
    dict(integrator="rk4", radius_every=3, neighbour_search="hash"),
    dict(integrator="rk4", radius_every=3, neighbour_search="all_pairs"),
    dict(adaptive_radius=False, obstacles=[], discs=[], neighbour_search="grid"),
]


@pytest.mark.parametrize("case", M3_CASES, ids=lambda c: "-".join(f"{v}" for v in c.values()))
# As M2's above: fused on what it runs, per_step on the rest and on each search.
@pytest.mark.fast_cases("fused-grid", "fused-2.0-everywhere", "fused-False-[]-[]-grid",
                        "per_step-all_pairs")
def test_m3_matches_reference_step_by_step(path, case):
    sc = m3_scenario(**dict(case))
    p = sc.model
    fused_or_skip(path, sc, case.get("neighbour_search") == "hash")
    k = make_kernel(sc, hashed=case.get("neighbour_search") == "hash", path=path)
    ref = M3Ref(p, sc.neighbours.radius, sc.inclusive)
    x, v = state(k)
    R = np.full(sc.n_agents, sc.neighbours.radius)
    dt, halved, grown = sc.time.dt, 0, 0
    for step in range(sc.time.steps):
        k.step(step)
        if p.adaptive_radius and step > 0 and step % p.radius_every == 0:
            R_new = ref.radius(x, v, R)
            halved += int((R_new < R).sum())
            grown += int((R_new > R).sum())
            R = R_new
        if p.integrator == "rk4":
            x, v = rk4(x, v, lambda x, v: ref.accel(x, v, R), dt)  # noqa: B023
        else:
            x, v = euler(x, v, ref.accel(x, v, R), dt)
        kx, kv = state(k)
        kR = k.state.in_id_order("rad")
        err = max(np.abs(kx - x).max(), np.abs(kv - v).max())
        assert err < TOL, f"step {step}: engine and reference differ by {err:.3g}"
        np.testing.assert_array_equal(kR, R, err_msg=f"radii differ at step {step}")
    counts = k.extra()["adaptive_radius"]
    assert (counts["halvings"], counts["increases"]) == (halved, grown)
    if case.get("neighbour_search") in ("grid", "hash") and path == "per_step":
        assert k.grid.layout == {"grid": "dense", "hash": "hash"}[case["neighbour_search"]]
    if p.adaptive_radius:
        assert halved > 0 and grown > 0  # both branches of eq. 4 were exercised


def test_sprawling_swarm_falls_back_to_the_hashed_grid(path):
    """A box needing more than 4 cells per agent is bucketed by the engine's hashed grid
    (the fused path: hashed buckets of its cells); the trajectory still matches the
    reference."""
    init = lattice(70, 1.1, 3)
    init["positions"][60:] = [[1000.0 + 1.1 * i, -500.0] for i in range(10)]
    sc = Scenario.model_validate({
        "model": {"kind": "flocking"}, "space": {"kind": "plane"},
        "neighbours": {"radius": 2.0}, "initial": init, "time": {"steps": 50, "dt": 0.01},
    })
    k = make_kernel(sc, path=path)
    x, v = state(k)
    for step in range(sc.time.steps):
        k.step(step)
        x, v = euler(x, v, m2_accel(x, v, a=1.0, R=2.0), sc.time.dt)
    kx, kv = state(k)
    assert path == "fused" or k.grid.layout == "hash"
    assert max(np.abs(kx - x).max(), np.abs(kv - v).max()) < TOL


def sparse_m2_accel(x, v, *, a, R):
    """u_i of eq. 3 with switching neighbours |r_ij| < R from a k-d tree (O(N k))."""
    from scipy.spatial import cKDTree

    pairs = cKDTree(x).query_pairs(R * (1 + 1e-9), output_type="ndarray")
    i, j = pairs[:, 0], pairs[:, 1]
    d = x[j] - x[i]
    s2 = d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1]
    keep = s2 < R * R
    i, j, d, s2 = i[keep], j[keep], d[keep], s2[keep]
    s = np.sqrt(s2)
    f = (-2.0 * a / s**3 + 2.0 / s) / s
    term = (v[j] - v[i]) + f[:, None] * d  # on i; the pair's term on j is its negative
    u = np.zeros_like(x)
    np.add.at(u, i, term)
    np.add.at(u, j, -term)
    return u


@pytest.mark.parametrize("hashed", [False, True], ids=["dense", "hash"])
def test_m2_grid_matches_sparse_reference_at_scale(taichi_cpu, hashed):
    """20 000 agents on the plane grids against a k-d tree reference, 5 steps."""
    sc = m2_scenario("switching", n=20_000, steps=5, spacing=1.0, speed=0.5, search="grid")
    k = make_kernel(sc, hashed)
    x, v = state(k)
    for step in range(sc.time.steps):
        k.step(step)
        x, v = euler(x, v, sparse_m2_accel(x, v, a=1.0, R=2.0), sc.time.dt)
        kx, kv = state(k)
        assert max(np.abs(kx - x).max(), np.abs(kv - v).max()) < TOL
    assert k.grid.layout == ("hash" if hashed else "dense")


def test_navigation_reference_is_consistent():
    """The reference itself: its gradient matches central differences of its V."""
    rng = np.random.default_rng(0)
    centers = rng.uniform(-1, 1, size=(6, 2))
    radii = np.r_[np.zeros(4), 0.2, 0.1]
    x = rng.uniform(-1.5, 1.5, size=(40, 2))
    V, G = navigation_ref(x, np.array([0.3, -0.2]), centers, radii, 0.7, 1.5)
    h = 1e-6
    for c in range(2):
        e = np.zeros(2)
        e[c] = h
        vp, _ = navigation_ref(x + e, np.array([0.3, -0.2]), centers, radii, 0.7, 1.5)
        vm, _ = navigation_ref(x - e, np.array([0.3, -0.2]), centers, radii, 0.7, 1.5)
        np.testing.assert_allclose(G[:, c], (vp - vm) / (2 * h), atol=1e-6)
    assert np.all(V >= 0)
