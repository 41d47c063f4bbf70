"""M1 kernel: Vicsek and the Jadbabaie–Lin–Morse heading rules (paper 001).

One step, synchronous for all agents (state at t read, state at t+1 written elsewhere):
  S_i = sums over the closed neighbourhood N_i ∪ {i}, N_i = {j : |r_ij| <= r} (eq. 2 text)
  vicsek    theta_i' = atan2(sum sin theta_j, sum cos theta_j) + xi_i; held as the unit
            vector e(theta_i') = R(xi_i) s / |s|, s = sum e(theta_j): no atan2 per step
            (theta = atan2(e) when a heading is asked for, in (-pi, pi])
  average   theta_i' = sum theta_j / (1 + n_i)                       (eq. 1-2, F = (I+D)^-1 (A+I))
  laplacian theta_i' = theta_i - ((1 + n_i) theta_i - sum theta_j) / g   (eq. 17-18)
  leader    as average, with agent 0 (the leader) in the sums whenever within r and its
            own heading held at theta_0 (eq. 22: its b_i theta_0 term)
  x_i' = x_i + v0 dt (cos phi_i, sin phi_i), phi = theta (old, default) or theta'.
xi_i = eta (u - 1/2), u from the counter-based hash of (seed, step, agent id).

3D (rule vicsek only, the same source with dim = 3): e_i' = the mean direction s / |s|
turned to a direction uniform in the spherical cap of half-angle eta/2 around it: polar
angle t with cos t uniform in [cos(eta/2), 1] (uniform in area), azimuth uniform in
[0, 2 pi), two counter-based draws (streams 0 and 1). docs/MODELS_3D.md relates it to the
2D rule and to the vectorial noise of the literature.
"""

from functools import cache
from typing import Any

import numpy as np
import taichi as ti

from flocklab.schemas import PeriodicBox, Scenario, VicsekParams

from ...model import ModelKernel, register_kernel
from ...result import SimulationDiverged
from ...runtime import DevicePolicy, as_real, wide
from ...space import rng, trig
from ...space.graph import MetricGraph, count_roots, find, link, reset_parent
from ...space.grid import Grid, make_visitor, row, set_row, within
from ...space.initial import initial_state
from ...space.params import Slots
from ...space.state import SortedState
from .fused import VicsekBatch
from .noise import cap_turn

nd = ti.types.ndarray()
RULES = {"vicsek": 0, "average": 1, "laplacian": 2, "leader": 3}
# The parameter array: r^2, v0 dt, eta, g (laplacian), L (periodic box), theta_0 (leader),
# and 1 - cos(eta/2) (3D: the spherical cap's height).
P = Slots("R2", "V0DT", "ETA", "G", "L", "THETA0", "CAP")
_TWO_PI = 2 * np.pi


@ti.kernel
def _arc_buckets(ew: nd, lo: nd, hi: nd, nb: ti.i32):
    """Headings (from unit vectors ew) mod 2 pi into nb equal buckets, keeping each
    bucket's min and max (order-independent: the result is exact and deterministic)."""
    for b in range(nb):
        lo[b] = ti.math.inf
        hi[b] = -ti.math.inf
    for i in range(ew.shape[0]):
        e = row(ew, i, 2)
        th = ti.atan2(e[1], e[0])
        a = th - _TWO_PI * ti.floor(th / _TWO_PI)
        if a >= _TWO_PI:
            a -= _TWO_PI
        b = ti.min(ti.cast(a / _TWO_PI * nb, ti.i32), nb - 1)
        ti.atomic_min(lo[b], a)
        ti.atomic_max(hi[b], a)


@ti.kernel
def _largest_gap(lo: nd, hi: nd, nb: ti.i32) -> float:
    """The largest gap on the circle between the extremes of consecutive non-empty
    buckets: a gap between consecutive headings. Every gap inside a bucket is narrower
    than a bucket, so a result at least a bucket wide is the largest gap of all."""
    ti.loop_config(serialize=True)
    first = ti.math.inf
    last = -ti.math.inf
    gap = 0.0
    for b in range(nb):
        if lo[b] <= hi[b]:
            if last > -ti.math.inf:
                gap = ti.max(gap, lo[b] - last)
            else:
                first = lo[b]
            last = hi[b]
    return ti.max(gap, first + _TWO_PI - last)


@cache
def step_kernel(rule: int, inclusive: bool, periodic: bool, move_new: bool, with_graph: bool,
                dim: int = 2):
    """Compile-time specialised step for one rule, geometry and dimension. `with_graph`
    also fills the graph observables of G(t) from the same neighbour visit: each agent's
    degree, and the union of every edge into `parent` (slot-indexed) for the components."""

    # The sums' last lane counts the closed neighbourhood: the JLM rules average over it,
    # the vicsek rule needs it only for the degrees.
    counted = rule != RULES["vicsek"] or with_graph

    @ti.func
    def pair(i, k, d, acc, S: ti.template()):
        ew, theta, prm, parent = ti.static(S[0], S[1], S[2], S[3])
        # Branch-free accumulation: w is 1 for a neighbour, 0 otherwise.
        w = ti.cast(within(d.dot(d), prm[P.R2], inclusive), float)
        if ti.static(rule == RULES["vicsek"]):
            ek = row(ew, k, dim)
            if ti.static(counted):
                acc += w * ti.Vector([ek[c] for c in ti.static(range(dim))] + [1.0])
            else:  # the count is for the degrees only: one add a pair fewer without them
                acc += w * ek
        else:
            acc += w * ti.math.vec3(theta[k], 0.0, 1.0)
        if ti.static(with_graph):
            if w > 0.0 and k > i:
                ri = find(parent, i)
                rk = find(parent, k)
                if ri != rk:
                    link(parent, ri, rk)
        return acc

    visit = make_visitor(pair, dim=dim)

    @ti.kernel
    def step(pos: nd, theta: nd, ew: nd, ids: nd, pos_out: nd, theta_out: nd, ew_out: nd,
             prm: nd, key: ti.u32, key2: ti.u32, bad: nd, parent: nd, deg: nd,
             start: nd, cid: nd, gf: nd, gi: nd):
        for i in range(pos.shape[0]):
            xi = row(pos, i, dim)
            acc = visit(i, xi, ti.Vector.zero(float, dim + int(counted)), pos,
                        ti.static((start, cid, gf, gi)),
                        ti.static((ew, theta, prm, parent)), periodic)
            if ti.static(with_graph):
                deg[i] = ti.cast(acc[dim], ti.i32) - 1  # the closed neighbourhood holds i
            th = 0.0
            if ti.static(rule != RULES["vicsek"]):
                th = theta[i]
            new = th
            e_new = ti.Vector.unit(dim, 0, float)
            if ti.static(rule == RULES["vicsek"]):
                nrm2 = acc[0] * acc[0] + acc[1] * acc[1]
                if ti.static(dim == 3):
                    nrm2 += acc[2] * acc[2]
                nrm = ti.sqrt(nrm2)
                if nrm > 0.0:  # arg(0) = 0, as atan2(0, 0); in 3D the x axis
                    for c in ti.static(range(dim)):
                        e_new[c] = acc[c] / nrm
            elif ti.static(rule == RULES["laplacian"]):
                new = th - (acc[2] * th - acc[0]) / prm[P.G]
            else:
                new = acc[0] / acc[2]
            if ti.static(dim == 3):
                if prm[P.ETA] > 0.0:
                    e_new = cap_turn(e_new, rng.uniform(key, ids[i]),
                                     rng.uniform(key2, ids[i]), prm[P.CAP])
            elif prm[P.ETA] > 0.0:
                noise = prm[P.ETA] * (rng.uniform(key, ids[i]) - 0.5)
                if ti.static(rule == RULES["vicsek"]):
                    cs = trig.cos_sin(noise)  # rotate e_new by the noise angle
                    cx = cs[0]
                    sx = cs[1]
                    ex = e_new[0]
                    ey = e_new[1]
                    e_new = ti.math.vec2(cx * ex - sx * ey, sx * ex + cx * ey)
                else:
                    new += noise
            if ti.static(rule == RULES["leader"]):
                if ids[i] == 0:
                    new = prm[P.THETA0]
            if ti.static(rule != RULES["vicsek"]):
                e_new = ti.math.vec2(ti.cos(new), ti.sin(new))
            e = row(ew, i, dim)  # e(theta_i(t))
            if ti.static(move_new):
                e = e_new
            x = xi + prm[P.V0DT] * e
            if ti.static(periodic):
                L = prm[P.L]
                # x - L floor(x / L) is x itself for x in [0, L) (x / L < 1 there, in
                # rounding too): the division only for an agent that crossed the box.
                for c in ti.static(range(dim)):
                    if x[c] < 0.0 or x[c] >= L:
                        x[c] -= L * ti.floor(x[c] / L)
                        if x[c] >= L:  # x - L floor(x / L) can round up to L itself
                            x[c] -= L
            set_row(pos_out, i, x)
            if ti.static(rule != RULES["vicsek"]):
                theta_out[i] = new
            # The unit vectors travel with the state: each heading's cos and sin (2D) are
            # computed once, here.
            set_row(ew_out, i, e_new)
            v = new + x[0] + x[1] + e_new[0]  # NaN if any term is NaN or infinite
            if ti.static(dim == 3):
                v += x[2] + e_new[1] + e_new[2]
            if ti.math.isnan(v) or ti.math.isinf(v):
                ti.atomic_add(bad[0], 1)

    return step


@register_kernel
class VicsekKernel(ModelKernel):
    kind = "vicsek"
    batch = VicsekBatch

    def __init__(self, scenario: Scenario, policy: DevicePolicy):
        super().__init__(scenario, policy)
        p: VicsekParams = scenario.model  # type: ignore[assignment]
        self.p = p
        self.n = n = scenario.n_agents
        self.periodic = isinstance(scenario.space, PeriodicBox)
        self.dim = dim = scenario.dimension
        L = scenario.space.L if self.periodic else 0.0
        radius = scenario.neighbours.radius
        init = initial_state(scenario)
        theta = init.headings
        if p.rule == "leader":
            theta[0] = p.leader_heading
        if dim == 3:  # rule vicsek (validated): the unit vectors are the state
            ew = init.directions
        else:
            ew = np.stack([np.cos(theta), np.sin(theta)], axis=1)
        # The vicsek rule's headings are angles: the unit vectors are the whole state.
        arrays = {"pos": init.positions, "ew": ew}
        if p.rule != "vicsek":
            arrays["theta"] = theta
        # Positions and unit vectors as rows of vectors: one load per neighbour candidate.
        self.state = SortedState(arrays, vectors=("pos", "ew"))
        self._swap = tuple(arrays)
        self._no_theta = ti.ndarray(float, shape=1)  # stands in for theta (vicsek rule)
        self.grid = Grid(n, radius, L if self.periodic else None, policy, dim)
        self.graph = MetricGraph(n, radius, scenario.inclusive, self.periodic, dim)
        self.prm = ti.ndarray(float, shape=P.size)
        self.prm.from_numpy(as_real(P.pack(
            R2=radius * radius, V0DT=p.v0 * scenario.time.dt, ETA=p.eta, G=p.g or 1.0, L=L,
            THETA0=p.leader_heading, CAP=1.0 - np.cos(p.eta / 2),
        )))
        self.bad = ti.ndarray(ti.i32, shape=1)
        if p.rule == "vicsek" and dim == 2:
            self._arc_lo = ti.ndarray(float, shape=n)
            self._arc_hi = ti.ndarray(float, shape=n)
        variant = (RULES[p.rule], scenario.inclusive, self.periodic,
                   p.position_update == "new_heading")
        self.kernel = step_kernel(*variant, False, dim)
        self.kernel_with_graph = step_kernel(*variant, True, dim)
        track = p.track_linked_intervals
        self.track = n <= 100_000 if track is None else track
        if self.track:
            self.parent_u = ti.ndarray(ti.i32, shape=n)
            reset_parent(self.parent_u)
            self.linked = {"count": 0, "longest": 0, "open_since": 0}
        self._advanced_for = -1  # the step whose next state observe() already computed
        self._graph_for = -1  # the step whose G(t) graph.deg holds (slot order)

    def _advance(self, step: int, with_graph: bool) -> None:
        """Compute the state at step + 1 into the scratch buffers (and, with_graph, the
        degrees and components of G(step) from the same visit)."""
        st = self.state
        self.bad.fill(0)
        if with_graph:
            reset_parent(self.graph.parent)
        kernel = self.kernel_with_graph if with_graph else self.kernel
        kernel(
            st["pos"], self._theta(st.cur), st["ew"], st.ids, st.scratch("pos"),
            self._theta(st.scratch_all()), st.scratch("ew"), self.prm,
            rng.step_key(self.scenario.seed, 0, step), rng.step_key(self.scenario.seed, 1, step),
            self.bad,
            self.graph.parent, self.graph.deg, *self.grid.view(),
        )
        self._advanced_for = step
        if with_graph:
            self._graph_for = step

    def step(self, step: int) -> None:
        self.state.sort(self.grid, step)
        st = self.state
        if self.track:
            self._track_linked(step)
        if self._advanced_for != step:
            self._advance(step, with_graph=False)
        for name in self._swap:
            st.swap(name)
        if self.bad.to_numpy()[0]:
            raise SimulationDiverged(
                step, "heading/position",
                "non-finite input (v0 * dt or the initial state too large for float64)",
            )

    def _track_linked(self, step: int) -> None:
        """Theorem 2: contiguous intervals over which the union of the graphs is connected."""
        st = self.state
        self.graph.union_edges(self.grid, st["pos"], st.ids, parent=self.parent_u)
        self._graph_for = -1  # that pass wrote its own degrees over graph.deg
        if count_roots(self.parent_u) == 1:
            lk = self.linked
            lk["count"] += 1
            lk["longest"] = max(lk["longest"], step + 1 - lk["open_since"])
            lk["open_since"] = step + 1
            reset_parent(self.parent_u)

    def observe(self, step: int) -> dict[str, float]:
        self.state.sort(self.grid, step)
        st = self.state
        e = wide(st["ew"])  # unit vectors e(theta_i); column sums: 15x numpy's sum(0)
        if self.dim == 3:
            obs = self._observe_3d(e)
        else:
            obs = {"polarization": float(np.hypot(e[:, 0].sum(), e[:, 1].sum()) / self.n)}
            if self.p.rule == "vicsek":
                obs["heading_spread"] = self.circular_spread(st["ew"])
            else:
                theta = wide(st["theta"])
                obs["heading_spread"] = float(theta.max() - theta.min())
            if self.p.rule == "leader":
                obs["leader_error"] = float(np.abs(theta - self.p.leader_heading).max())
        # The graph observables come from the step's own neighbour visit: observing then
        # stepping costs one visit, not two (the last observation computes a step unused).
        self._advance(step, with_graph=True)
        obs.update(self.graph.summary())
        if self.track:
            obs["linked_intervals"] = float(self.linked["count"])
        return obs

    def _observe_3d(self, e: np.ndarray) -> dict[str, float]:
        """Polarization |sum e_i| / N, and as the heading spread twice the largest angle
        between a heading and the mean heading (0 exactly when all are aligned; an upper
        bound on the angle between any two; 2 pi when the headings cancel)."""
        s = np.array([e[:, c].sum() for c in range(3)])
        norm = float(np.sqrt(s @ s))
        spread = 2 * np.pi
        if norm > 0:
            spread = float(2 * np.arccos(np.clip((e @ (s / norm)).min(), -1.0, 1.0)))
        return {"polarization": norm / self.n, "heading_spread": spread}

    def frame(self, arrays: list[str]) -> dict[str, np.ndarray]:
        ids = self.state.ids_numpy()
        out = {}
        if "position" in arrays:
            out["position"] = self.state.in_id_order("pos", ids)
        if self.dim == 3:  # headings are the unit vectors (N, 3)
            e = self.state.in_id_order("ew", ids)
            if "heading" in arrays:
                out["heading"] = e
            if "velocity" in arrays:
                out["velocity"] = self.p.v0 * e
            return out
        if "heading" in arrays:
            out["heading"] = self._headings(ids)
        if "velocity" in arrays:
            th = self._headings(ids)
            out["velocity"] = self.p.v0 * np.stack([np.cos(th), np.sin(th)], axis=1)
        return out

    def derived_arrays(self, step: int, names: list[str]) -> dict[str, np.ndarray]:
        """degree: |N_i| in G(step), from the step's own neighbour visit, as the degree_*
        observables count it (an observation at this step has already made it)."""
        self.state.sort(self.grid, step)  # the sort step(step) would do: no bit changes
        if self._graph_for != step:
            self._advance(step, with_graph=True)  # step(step) then reuses the next state
        deg = np.empty(self.n, dtype=np.int32)
        deg[self.state.ids_numpy()] = self.graph.deg.to_numpy()
        return {"degree": deg}

    def _theta(self, arrays: dict[str, ti.Ndarray]) -> ti.Ndarray:
        return arrays.get("theta", self._no_theta)

    def _headings(self, ids: np.ndarray) -> np.ndarray:
        """Headings in agent-id order (vicsek rule: atan2 of the unit vectors)."""
        if "theta" in self.state.cur:
            return self.state.in_id_order("theta", ids)
        e = self.state.in_id_order("ew", ids)
        return np.arctan2(e[:, 1], e[:, 0])

    def circular_spread(self, ew: ti.Ndarray) -> float:
        """Length of the shortest arc holding every heading e_i (= `circular_spread`)."""
        if self.n < 2:
            return 0.0
        # N/8 buckets first (8x less memory touched): exact whenever the largest gap they
        # show is a bucket wide, as for a disordered swarm of more than ~3000 agents
        # (largest gap ~ 2 pi ln N / N) and any aligned one. Else N buckets: by
        # pigeonhole some gap between buckets is then at least a bucket wide.
        if self.n >= 16:
            nb = self.n // 8
            _arc_buckets(ew, self._arc_lo, self._arc_hi, nb)
            gap = _largest_gap(self._arc_lo, self._arc_hi, nb)
            if gap > 2 * np.pi / nb * (1 + 1e-6):  # a hair over: a bucket's rounded edges
                return float(2 * np.pi - gap)
        _arc_buckets(ew, self._arc_lo, self._arc_hi, self.n)
        return float(2 * np.pi - _largest_gap(self._arc_lo, self._arc_hi, self.n))

    def convergence_keys(self) -> list[str]:
        keys = ["heading_spread"]
        if self.p.rule == "leader":
            keys.append("leader_error")
        return keys

    def extra(self) -> dict[str, Any]:
        if not self.track:
            return {}
        return {
            "linked_intervals": {
                "count": self.linked["count"],
                "longest_steps": self.linked["longest"],
                "open_since_step": self.linked["open_since"],
            }
        }
