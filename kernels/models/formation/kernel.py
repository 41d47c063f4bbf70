"""M4 kernel: Xi–Abed formation control with virtual leaders (paper 003).

Right-hand side, for every agent at once from the state at time t (eq. 1-2, 6, 12):
  rdot_i = f(|l_i - r_i|) (l_i - r_i)/|l_i - r_i|                 attraction (eq. 3 / eq. 5)
         + sum_{j : |r_ij| < d} g(|r_ji|) r_ji/|r_ji|,  r_ji = r_j - r_i    repulsion (eq. 4)
  l_i = r_id(t) = p(t) + b_i(t) (F1, eq. 3)  or  r_0(t) = p(t) (F2, eq. 5)
Integrators: explicit Euler r(t + dt) = r(t) + dt rdot(t); classical RK4 with stages at t,
t + dt/2, t + dt (each stage re-buckets its positions, so neighbours are always exact).
Neighbours come from the plane's grid of cells of side d (kernels/space/plane_grid.py: row-major
dense cells while the swarm is compact on a CPU, else the hashed grid); g(d) = 0, so < and <=
give the same forces.
Above `max_exact_candidates` an Euler step coarse-grains far pairs (dense.py).
Two agents at the same position (g singular) stop the run.

Observables (at observation steps only): formation error against r_id + a with the lag a of
eq. 8, the centroid's distance to p(t), speeds against the leader's, the minimum pairwise
distance, V1 (eq. 10) or V2 (eq. 16), and for F2 the properties D1-D3.

3D (`space.dimension = 3`): the same kernels compiled with dim = 3 on the grid's 27 cells;
p(t), b_i(t) and the rates are 3-vectors; `leader_z` and `centroid_z` join the observables.
The dense regime (dense.py) is 2D: 3D steps are always exact.
"""

from collections.abc import Mapping
from functools import cache
from typing import Any

import numpy as np
import taichi as ti

from flocklab.schemas import Scenario
from flocklab.schemas.formation import FormationParams, SaturatingF

from ... import runtime
from ...checkpoint import CheckpointMismatch
from ...model import ModelKernel, register_kernel
from ...result import SimulationDiverged
from ...runtime import DevicePolicy, as_real, wide
from ...space.graph import count_roots, flatten, reset_parent
from ...space.grid import Grid, make_visitor, permute, permute_rows, row, within
from ...space.initial import initial_state
from ...space.integrate import count_nonfinite, gather_rows, rk4_begin, rk4_finish, rk4_stage
from ...space.plane_grid import PlaneGrid, make_dense_visitor
from ...space.state import SortedState
from ...space.stream import PairwiseSum, Rows, RowSum, blocks
from .components import union_kernel
from .dense import bucket_aggregates, coarse_euler, max_count, stencil_reach
from .forces import (
    F_KINDS,
    G_KINDS,
    P,
    attract,
    attraction_energy,
    force_params,
    g_over_s,
    lag_length,
    lead_slots,
    leader,
    leader_3d,
    pair_energy,
)
from .fused import FormationBatch
from .norms import norms
from .path import make_path
from .props import Isolated, surrounds_2d, surrounds_3d_all
from .schedule import OffsetSchedule

nd = ti.types.ndarray()
_NO_PAIR = 1e300  # nearest-candidate sentinel


@cache
def formation_kernels(fkind: int, gkind: int, f1: bool, blend: bool, inclusive: bool,
                      dim: int = 2, search: str = "hash"):
    """Compile-time specialised kernels: one Euler step, rates at a time slot, observation,
    over the grid layout `search` (PlaneGrid.layout: "dense" or "hash").
    Positions are dim-vectors (2 or 3); the rate accumulator holds the dim components of
    the repulsion, then the count of coincident neighbours."""
    lead = leader if dim == 2 else leader_3d
    # the observation accumulator: repulsion (dim), coincident, degree, sum of G, nearest d^2
    CO, DEG, GS, NEAR = dim, dim + 1, dim + 2, dim + 3

    @ti.func
    def pair_rate(i, k, dv, acc, S: ti.template()):
        prm = ti.static(S[0])
        d2 = dv.dot(dv)
        if k != i and within(d2, prm[P.D2], inclusive):
            if d2 > 0.0:
                w = g_over_s(ti.sqrt(d2), prm, gkind)
                add = ti.Vector.zero(float, dim + 1)
                for c in ti.static(range(dim)):
                    add[c] = w * dv[c]
                acc += add
            else:
                acc[CO] += 1.0  # coincident agents
        return acc

    @ti.func
    def pair_obs(i, k, dv, acc, S: ti.template()):
        prm = ti.static(S[0])
        d2 = dv.dot(dv)
        if k != i:
            acc[NEAR] = ti.min(acc[NEAR], d2)
            if within(d2, prm[P.D2], inclusive):
                acc[DEG] += 1.0
                if d2 > 0.0:
                    s = ti.sqrt(d2)
                    w = g_over_s(s, prm, gkind)
                    for c in ti.static(range(dim)):
                        acc[c] += w * dv[c]
                    acc[GS] += pair_energy(s, prm, gkind)
                else:
                    acc[CO] += 1.0
        return acc

    def make(pair):
        return make_dense_visitor(pair, dim) if search == "dense" else make_visitor(pair, dim=dim)

    visit_rate, visit_obs = make(pair_rate), make(pair_obs)

    @ti.func
    def rate(i, pos: ti.template(), ids: ti.template(), ba: ti.template(), bb: ti.template(),
             prm: ti.template(), slot, G: ti.template()):
        """(rdot, coincident neighbours) of agent slot i, a (dim + 1)-vector."""
        xi = row(pos, i, dim)
        acc = visit_rate(i, xi, ti.Vector.zero(float, dim + 1), pos, G, ti.static((prm,)),
                         False)
        v = attract(lead(i, ids, ba, bb, prm, slot, f1, blend) - xi, prm, fkind)
        out = ti.Vector.zero(float, dim + 1)
        for c in ti.static(range(dim)):
            out[c] = v[c] + acc[c]
        out[CO] = acc[CO]
        return out

    @ti.func
    def flag(bad: ti.template(), x, coincident):
        if coincident > 0.0:
            ti.atomic_add(bad[1], 1)
        s = x[0]
        for c in ti.static(range(1, dim)):
            s += x[c]  # NaN if any is NaN or infinite
        if ti.math.isnan(s) or ti.math.isinf(s):
            ti.atomic_add(bad[0], 1)

    @ti.kernel
    def euler(pos: nd, ids: nd, ba: nd, bb: nd, pos_out: nd, prm: nd, bad: nd,
              start: nd, cid: nd, gf: nd, gi: nd):
        for i in range(pos.shape[0]):
            r = rate(i, pos, ids, ba, bb, prm, 0, ti.static((start, cid, gf, gi)))
            x = ti.Vector.zero(float, dim)
            for c in ti.static(range(dim)):
                x[c] = pos[i, c] + prm[P.DT] * r[c]
                pos_out[i, c] = x[c]
            flag(bad, x, r[CO])

    @ti.kernel
    def rates(pos: nd, ids: nd, ba: nd, bb: nd, vel: nd, prm: nd, slot: ti.i32, bad: nd,
              start: nd, cid: nd, gf: nd, gi: nd):
        for i in range(pos.shape[0]):
            r = rate(i, pos, ids, ba, bb, prm, slot, ti.static((start, cid, gf, gi)))
            for c in ti.static(range(dim)):
                vel[i, c] = r[c]
            flag(bad, r, r[CO])

    @ti.kernel
    def observe(pos: nd, ids: nd, ba: nd, bb: nd, vel: nd, aux: nd, prm: nd,
                start: nd, cid: nd, gf: nd, gi: nd):
        for i in range(pos.shape[0]):
            xi = row(pos, i, dim)
            init = ti.Vector([0.0] * (dim + 3) + [_NO_PAIR])
            acc = visit_obs(i, xi, init, pos, ti.static((start, cid, gf, gi)),
                            ti.static((prm,)), False)
            v = attract(lead(i, ids, ba, bb, prm, 0, f1, blend) - xi, prm, fkind)
            for c in ti.static(range(dim)):
                vel[i, c] = v[c] + acc[c]
            aux[i, 0] = acc[DEG]
            aux[i, 1] = acc[GS]
            aux[i, 2] = acc[NEAR]

    return euler, rates, observe


@register_kernel
class FormationKernel(ModelKernel):
    kind = "formation"
    fused = FormationBatch

    def __init__(self, scenario: Scenario, policy: DevicePolicy):
        super().__init__(scenario, policy)
        p: FormationParams = scenario.model  # type: ignore[assignment]
        self.p = p
        self.n = n = scenario.n_agents
        self.d = d = scenario.neighbours.radius
        self.dt = dt = scenario.time.dt
        self.f1 = p.design == "F1"
        self.dim = dim = scenario.dimension
        self.wants_d3 = scenario.recording.wants("D3")  # F2's costliest observable
        init = initial_state(scenario)
        self.path = make_path(p.path, init.positions.mean(axis=0))
        if isinstance(p.attraction, SaturatingF):
            top = float(norms(self.path.velocity(0.0)))
            if top >= p.attraction.v_max:
                raise ValueError(
                    f"leader speed {top:g} >= attraction.v_max = {p.attraction.v_max:g}: "
                    "the agents could never keep up (eq. 8 has no solution)"
                )
        self.schedule = (OffsetSchedule(p.formation, p.schedule, n, d, dim) if self.f1
                         else None)
        self.state = SortedState({"pos": init.positions})
        del init  # the host positions, before the other device arrays
        self.grid = PlaneGrid(n, d, policy, dim)
        self.parent: ti.Ndarray | None = None  # F2's union-find forest, at observations
        self.r2 = ti.ndarray(float, shape=1)  # d^2, for the graph's kernel
        self.r2.from_numpy(as_real([d * d]))
        self.prm_host = force_params(p, d, dt, dim)
        self.prm = ti.ndarray(float, shape=self.prm_host.shape)
        # The offsets of the (at most two) stored formations in use: the second only when
        # the schedule stores more than one (F1 with a change to a new formation).
        held = 0 if not self.f1 else min(len(self.schedule.stored), 2)
        self.b_dev = [ti.ndarray(float, shape=(n if k < held else 1, dim)) for k in range(2)]
        self.b_held: list[int | None] = [None, None]
        self.bad = ti.ndarray(ti.i32, shape=2)
        self.fkind = F_KINDS[p.attraction.kind]
        self.gkind = G_KINDS[p.repulsion.kind]
        self.inclusive = scenario.inclusive
        if p.integrator == "rk4":
            self.grid2 = PlaneGrid(n, d, policy, dim)
            self.tmp_pos = ti.ndarray(float, shape=(n, dim))
            self.tmp_ids = ti.ndarray(ti.i32, shape=n)
            # RK4's stage state, rates and weighted sum of the rates (kernels/space/integrate.py)
            self.rk4 = {k: ti.ndarray(float, shape=(n, dim)) for k in ("ys", "k", "yk")}
        self.aux: ti.Ndarray | None = None  # per slot: degree, pair energy, nearest d^2
        # The dense regime's coarse step is 2D: 3D Euler steps are always exact.
        self.cap = p.max_exact_candidates if p.integrator == "euler" and dim == 2 else None
        self.fine: tuple[int, Grid] | None = None  # the dense regime's grid, by reach m
        self.agg: tuple | None = None
        self.coarse_steps, self.max_reach = 0, 1  # steps in the dense regime, largest m
        self.now = 0  # the step index of the current state

    # --- time-dependent leader data -----------------------------------------------------

    def _load_times(self, times: list[float]) -> bool:
        """Write p(t) and the offset weights of each slot; True when formation B is used."""
        weights = [self.schedule.weights(t) if self.f1 else {} for t in times]
        used = sorted({k for w in weights for k in w})
        if len(used) > 2:
            raise ValueError("formation changes closer together than one time step dt")
        for k in used:
            if k not in self.b_held:
                self._hold(next(j for j in range(2) if self.b_held[j] not in used), k)
        dim = self.dim
        slots, lead = lead_slots(dim)
        for s, (t, w) in enumerate(zip(times, weights, strict=True)):
            o = slots.LEAD + lead.size * s
            self.prm_host[o + lead.PX: o + lead.PX + dim] = self.path.position(t)
            mats = [w.get(self.b_held[j], np.zeros((dim, dim))) for j in range(2)]
            self.prm_host[o + lead.A00: o + lead.A00 + dim * dim] = mats[0].ravel()
            self.prm_host[o + lead.B00: o + lead.B00 + dim * dim] = mats[1].ravel()
        self.prm.from_numpy(as_real(self.prm_host))
        return any(self.b_held[1] in w for w in weights)

    def _hold(self, j: int, k: int) -> None:
        """Put stored formation k's offsets into device slot j (the kernels' ba, bb)."""
        self.b_dev[j].from_numpy(as_real(self.schedule.stored[k]))
        self.b_held[j] = k
        if runtime.real() is np.float64 and len(self.schedule.stored) <= 2:
            # Held for the whole run and exact on the device: no host copy.
            self.schedule.release(k, Rows(self.b_dev[j]).take)

    def _kernels(self, blend: bool, grid: PlaneGrid):
        """(euler, rates, observe) for positions bucketed in `grid` (its layout as built)."""
        return formation_kernels(self.fkind, self.gkind, self.f1, blend, self.inclusive,
                                 self.dim, grid.layout)

    # --- stepping -------------------------------------------------------------------------

    def _check(self, step: int) -> None:
        bad = self.bad.to_numpy()
        if bad[1]:
            raise SimulationDiverged(
                step, "position", "two agents at the same position, where g is singular "
                "(dt too large lets agents jump onto each other)"
            )
        if bad[0]:
            raise SimulationDiverged(
                step, "position", "non-finite position (dt too large for the repulsion's "
                "stiffness at close range)"
            )

    def _reach(self, step: int) -> int:
        """Sort the state for an Euler step: by the d-grid (returns 1, exact), or, when the
        densest d-cell holds more than cap/9 agents, by a grid of side d/m (returns m)."""
        self.state.sort(self.grid, step)
        if self.cap is None:
            return 1
        densest = max_count(self.grid.view()[0], self.grid.n_buckets)
        if 9 * densest <= self.cap:
            return 1
        m = stencil_reach(densest)
        if self.fine is None or self.fine[0] != m:
            self.fine = (m, Grid(self.n, self.d / m, None, self.policy))
        fine = self.fine[1]
        fine.build(self.state["pos"], step)
        self.state.resort(fine)
        self.state.forget_sort()
        if self.agg is None:
            self.agg = (ti.ndarray(float, shape=(fine.n_buckets, 3)),
                        ti.ndarray(ti.i64, shape=fine.n_buckets))
        start, cid, _, _ = fine.view()
        bucket_aggregates(self.state["pos"], start, cid, *self.agg)
        return m

    def step(self, step: int) -> None:
        st = self.state
        t = step * self.dt
        self.bad.fill(0)
        if self.p.integrator == "euler":
            m = self._reach(step)
            if m > 1:
                self.coarse_steps += 1
                self.max_reach = max(self.max_reach, m)
            blend = self._load_times([t])
            if m == 1:
                euler, _, _ = self._kernels(blend, self.grid)
                euler(st["pos"], st.ids, *self.b_dev, st.scratch("pos"), self.prm, self.bad,
                      *self.grid.view())
            else:
                coarse = coarse_euler(self.fkind, self.gkind, self.f1, blend, self.inclusive)
                coarse(st["pos"], st.ids, *self.b_dev, st.scratch("pos"), self.prm, self.bad,
                       m, *self.agg, *self.fine[1].view())
            self._check(step)
            st.swap("pos")
            self.now = step + 1
            return
        self.state.sort(self.grid, step)
        blend = self._load_times([t, t + 0.5 * self.dt, t + self.dt])
        _, rates, _ = self._kernels(blend, self.grid)
        x, b, h = st["pos"], self.rk4, self.dt
        rk4_begin(x, b["ys"], b["yk"])
        rates(x, st.ids, *self.b_dev, b["k"], self.prm, 0, self.bad, *self.grid.view())
        for slot, w, c in ((1, 1.0, 0.5 * h), (1, 2.0, 0.5 * h), (2, 2.0, h)):
            rk4_stage(x, b["ys"], b["k"], b["yk"], w, c)
            self._rates_at(b["ys"], slot, b["k"], blend, step)
        rk4_finish(x, b["k"], b["yk"], h / 6.0, st.scratch("pos"))
        count_nonfinite(st.scratch("pos"), self.bad)
        self._check(step)
        st.swap("pos")
        self.now = step + 1

    def _rates_at(self, y, slot: int, out, blend: bool, step: int) -> None:
        """rdot at positions y (storage order): bucket y on a second grid, evaluate there
        (with the kernel of that grid's layout), bring the rates back to storage order."""
        g2 = self.grid2
        g2.build(y, step)
        _, rates, _ = self._kernels(blend, g2)
        permute_rows(y, self.tmp_pos, g2.perm)
        permute(self.state.ids, self.tmp_ids, g2.perm)
        # The rates in g2's order go to the state's spare buffer, which only the step's
        # last write (rk4_finish) needs.
        tmp_vel = self.state.scratch("pos")
        rates(self.tmp_pos, self.tmp_ids, *self.b_dev, tmp_vel, self.prm, slot, self.bad,
              *g2.view())
        gather_rows(tmp_vel, out, g2.perm)

    # --- observation ----------------------------------------------------------------------

    def _observe_arrays(self, step: int) -> tuple[ti.Ndarray, ti.Ndarray]:
        """(rates, aux) in storage order at time step * dt: the rates in the state's spare
        buffer (dead until the step writes it), aux = (degree, pair energy sum, nearest
        squared distance) per slot."""
        self.state.sort(self.grid, step)
        st = self.state
        blend = self._load_times([step * self.dt])
        _, _, observe = self._kernels(blend, self.grid)
        if self.aux is None:
            self.aux = ti.ndarray(float, shape=(self.n, 3))
        vel = st.scratch("pos")
        observe(st["pos"], st.ids, *self.b_dev, vel, self.aux, self.prm, *self.grid.view())
        return vel, self.aux

    def observe(self, step: int) -> dict[str, float]:
        """The observables from the device arrays read in blocks (kernels/space/stream.py:
        numpy's bits on whole arrays)."""
        t = step * self.dt
        vel, aux = self._observe_arrays(step)
        p, q = self.path.position(t), self.path.velocity(t)
        qn = float(norms(q))
        n = self.n
        st = self.state
        rows = {"pos": Rows(st["pos"]), "vel": Rows(vel), "aux": Rows(aux)}
        if self.f1:
            rows["ids"] = Rows(st.ids)
            lag = lag_length(self.p, qn)
            a = np.zeros(self.dim) if qn == 0.0 else (lag / qn) * q
            if self.p.lag_sign == "eq8":
                a = -a
        centroid = RowSum()
        sums = {k: PairwiseSum(n) for k in ("speed", "degree", "pair", "energy", "error")}
        low = {"speed": np.inf, "near": np.inf}
        high = {"speed": -np.inf, "speed_error": -np.inf, "mismatch": -np.inf,
                "error": -np.inf}
        isolated = Isolated(self.p.at_leader(self.d))

        def extremes(key: str, x: np.ndarray, least: bool = False) -> None:
            if least:
                low[key] = np.minimum(low[key], x.min())
            if key in high:
                high[key] = np.maximum(high[key], x.max())

        for lo, hi in blocks(n):
            x, v = rows["pos"].wide(lo, hi), rows["vel"].wide(lo, hi)
            ax = rows["aux"].wide(lo, hi)
            centroid.add(x)
            speed = norms(v)
            sums["speed"].add(speed)
            extremes("speed", speed, least=True)
            extremes("speed_error", np.abs(speed - qn))
            extremes("mismatch", norms(v - q))
            extremes("near", ax[:, 2], least=True)
            sums["degree"].add(ax[:, 0])
            sums["pair"].add(ax[:, 1])
            if self.f1:  # e_i = |r_i - (r_id + a)|, r_id = p + b_i(t)
                e = norms(x - (p + self.schedule.at(t, rows["ids"](lo, hi)) + a))
                sums["error"].add(e)
                extremes("error", e)
                sums["energy"].add(attraction_energy(self.p, e))
            else:
                dist = norms(x - p)
                sums["energy"].add(attraction_energy(self.p, dist))
                isolated.add(dist, ax[:, 0])
        c = centroid.total() / n
        obs = {
            "leader_x": float(p[0]), "leader_y": float(p[1]), "leader_speed": qn,
            "centroid_x": float(c[0]), "centroid_y": float(c[1]),
            "centroid_distance": float(norms(c - p)),
            "speed_min": float(low["speed"]), "speed_mean": sums["speed"].total() / n,
            "speed_max": float(high["speed"]),
            "speed_error_max": float(high["speed_error"]),
            "velocity_mismatch_max": float(high["mismatch"]),
            "min_distance": self._min_distance(float(low["near"])),
            "degree_mean": sums["degree"].total() / n,
        }
        if self.dim == 3:
            obs.update({"leader_z": float(p[2]), "centroid_z": float(c[2])})
        pair_part = 0.5 * sums["pair"].total()
        if self.f1:
            obs.update({
                "formation_error": sums["error"].total() / n,
                "formation_error_max": float(high["error"]),
                "lag": float(lag),
                "V1": sums["energy"].total() + pair_part,
            })
        else:
            obs["V2"] = sums["energy"].total() + pair_part
            obs.update(self._d_properties(p, isolated, obs["min_distance"]))
        return obs

    def _min_distance(self, nearest2: float) -> float:
        """Exact when some pair is closer than a grid cell; else exact by brute force at
        N <= 4096, and the cell width (a lower bound) beyond."""
        if nearest2 < _NO_PAIR:
            return float(np.sqrt(nearest2))
        if 2 <= self.n <= 4096:
            pos = wide(self.state["pos"])
            dist = norms(pos[:, None, :] - pos[None, :, :])
            np.fill_diagonal(dist, np.inf)
            return float(dist.min())
        return float(self.grid.view()[2].to_numpy()[0])  # either layout's cell side

    def _d_properties(self, p: np.ndarray, isolated: Isolated, min_dist: float
                      ) -> dict[str, float]:
        """D1-D3 of an F2 formation around r_0 = p(t)."""
        tol = isolated.tol
        collide = self.p.collision(self.d)
        if self.parent is None:
            self.parent = ti.ndarray(ti.i32, shape=self.n)
        reset_parent(self.parent)
        unite = union_kernel(self.inclusive, self.dim, self.grid.layout)
        unite(self.state["pos"], self.parent, self.r2, *self.grid.view())
        flatten(self.parent)  # each slot's component label: its root
        n_isolated = isolated.count()
        out = {"D1": float(min_dist >= collide), "D2": float(n_isolated == 0)}
        if self.wants_d3:
            out["D3"] = float(self._d3(p, tol))
        out["isolated"] = float(n_isolated)
        out["components"] = float(count_roots(self.parent))
        return out

    def _d3(self, p: np.ndarray, tol: float) -> bool:
        """D3 from the agents off r^ (|r_i - r^| > tol), read in blocks: False at once when
        a component has a single one (no line or plane through r^ has agents of it on both
        sides), else props.surrounds_2d / surrounds_3d_all on their labels and directions."""
        n = self.n
        pos, parent = Rows(self.state["pos"]), Rows(self.parent)
        far_count = np.zeros(n, dtype=np.int32)
        for lo, hi in blocks(n):
            far = norms(pos.wide(lo, hi) - p) > tol
            np.add.at(far_count, parent(lo, hi)[far], 1)
        lone = bool(np.any(far_count == 1))
        del far_count
        if lone:
            return False
        labs, dirs = [], []
        for lo, hi in blocks(n):
            rel = pos.wide(lo, hi) - p
            dist = norms(rel)
            far = dist > tol
            labs.append(parent(lo, hi)[far])
            if self.dim == 2:
                dirs.append(np.arctan2(rel[far, 1], rel[far, 0]))
            else:
                dirs.append(rel[far] / dist[far, None])
        lab = np.concatenate(labs)
        del labs
        d = np.concatenate(dirs)
        del dirs
        return surrounds_2d(lab, d) if self.dim == 2 else surrounds_3d_all(lab, d)

    def frame(self, arrays: list[str]) -> dict[str, np.ndarray]:
        self.state.sort(self.grid, self.now)
        ids = self.state.ids_numpy()
        out = {}
        if "position" in arrays:
            out["position"] = self.state.in_id_order("pos", ids)
        if "velocity" in arrays:
            vel = wide(self._observe_arrays(self.now)[0])
            out["velocity"] = np.empty_like(vel)
            out["velocity"][ids] = vel
        return out

    def save(self) -> dict[str, np.ndarray]:
        """Checkpoints: the sorted positions with their ids, the step of the state (the
        frame's), the dense regime's counters, and which stored formation each device
        slot holds (F1: the slot decides whether a step blends, `_load_times`). The
        leader's p(t) and the schedule's b_i(t) are functions of t alone; the grids, the
        union-find forest and the observation arrays are rebuilt at each use."""
        return {**self.state.save(),
                "formation/counters": np.array([self.now, self.coarse_steps,
                                                self.max_reach], np.int64),
                "formation/held": np.array([-1 if k is None else k for k in self.b_held],
                                           np.int64)}

    def load(self, state: Mapping[str, np.ndarray]) -> None:
        """Back from `save`, into a kernel freshly built from the same scenario."""
        held = [int(k) for k in state["formation/held"]]
        if len(held) != 2 or any(k >= (len(self.schedule.stored) if self.f1 else 0)
                                 for k in held):
            raise CheckpointMismatch(f"formation/held: {held} does not fit this schedule")
        self.state.load(state)
        self.now, self.coarse_steps, self.max_reach = (
            int(v) for v in state["formation/counters"])
        for j, k in enumerate(held):
            if k >= 0:
                self._hold(j, k)

    def convergence_keys(self) -> list[str]:
        return ["formation_error", "velocity_mismatch_max"] if self.f1 else [
            "velocity_mismatch_max"]

    def extra(self) -> dict[str, Any]:
        return {
            "leader_arrival_time": self.path.arrival_time,
            "dense_regime": {"steps": self.coarse_steps, "max_reach": self.max_reach},
        }
