"""M1 kernel: Vicsek and the Jadbabaie–Lin–Morse heading rules (paper 001).

The state (positions and unit headings e_i, the JLM rules' angles theta_i, in grid order),
its step and its observables. The update rules and their Taichi kernels are in step.py
(the per-agent visit, and the rule vicsek in the periodic box by cell blocks, bit for bit
the same); the 3D noise in noise.py (docs/MODELS_3D.md); the small-N batch in fused.py.
Headings are reported as theta = atan2(e) in (-pi, pi]; in 3D as the unit vectors.
"""

from collections.abc import Mapping
from typing import Any

import numpy as np
import taichi as ti

from flocklab.schemas import PeriodicBox, Scenario, VicsekParams

from ...checkpoint import put
from ...model import ModelKernel, register_kernel
from ...result import SimulationDiverged
from ...runtime import DevicePolicy, as_real, wide
from ...space import rng
from ...space.graph import MetricGraph, count_roots, reset_parent
from ...space.grid import Grid, row
from ...space.initial import initial_state
from ...space.knn import TopologicalNeighbours
from ...space.observables import TWO_PI, arc_bucket, on_circle
from ...space.state import SortedState
from .fused import VicsekBatch, VicsekBatched
from .law import RULES
from .step import P, block_step_kernel, step_kernel, topological_step_kernel

nd = ti.types.ndarray()
LINKED = ("count", "longest", "open_since")  # Theorem 2's counters


@ti.kernel
def _arc_buckets(ew: nd, lo: nd, hi: nd, nb: ti.i32):
    """Headings (from unit vectors ew) mod 2 pi into nb equal buckets, keeping each
    bucket's min and max (order-independent: the result is exact and deterministic)."""
    for b in range(nb):
        lo[b] = ti.math.inf
        hi[b] = -ti.math.inf
    for i in range(ew.shape[0]):
        e = row(ew, i, 2)
        a = on_circle(ti.atan2(e[1], e[0]))
        b = arc_bucket(a, nb)
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
    return ti.max(gap, first + TWO_PI - last)


@register_kernel
class VicsekKernel(ModelKernel):
    kind = "vicsek"
    fused = VicsekBatch
    batched = VicsekBatched

    def __init__(self, scenario: Scenario, policy: DevicePolicy):
        super().__init__(scenario, policy)
        p: VicsekParams = scenario.model  # type: ignore[assignment]
        self.p = p
        self.n = n = scenario.n_agents
        self.periodic = isinstance(scenario.space, PeriodicBox)
        self.dim = dim = scenario.dimension
        L = scenario.space.L if self.periodic else 0.0
        nb = scenario.neighbours
        radius = nb.radius
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
        # Topological: the k nearest on a grid with cells sized for k (kernels/space/knn.py),
        # searched each step; the metric graph then only holds the degrees and components.
        self.knn = None
        if nb.topological:
            self.knn = TopologicalNeighbours(n, nb.k, radius, scenario.inclusive,
                                             nb.symmetric, L if self.periodic else None,
                                             policy, dim)
            self.grid = self.knn.grid
        else:
            self.grid = Grid(n, radius, L if self.periodic else None, policy, dim)
        self._knn_for = -1  # the step whose state the k-NN lists are of
        self.graph = MetricGraph(n, radius or 0.0, scenario.inclusive, self.periodic, dim)
        self.prm = ti.ndarray(float, shape=P.size)
        self.prm.from_numpy(as_real(P.pack(
            R2=(radius or 0.0) ** 2, V0DT=p.v0 * scenario.time.dt, ETA=p.eta, G=p.g or 1.0, L=L,
            THETA0=p.leader_heading, CAP=1.0 - np.cos(p.eta / 2),
        )))
        self.bad = ti.ndarray(ti.i32, shape=1)
        if p.rule == "vicsek" and dim == 2:
            self._arc_lo = ti.ndarray(float, shape=n)
            self._arc_hi = ti.ndarray(float, shape=n)
        variant = (RULES[p.rule], scenario.inclusive, self.periodic,
                   p.position_update == "new_heading")
        vectorial = p.noise == "vectorial"
        if self.knn is not None:
            topo = (RULES[p.rule], self.periodic, p.position_update == "new_heading")
            self.kernel = topological_step_kernel(*topo, False, dim, nb.symmetric, vectorial)
            self.kernel_with_graph = topological_step_kernel(*topo, True, dim, nb.symmetric,
                                                             vectorial)
        else:
            self.kernel = step_kernel(*variant, False, dim, vectorial)
            if p.rule == "vicsek" and self.grid.blocks and policy.cell_blocks:  # same bits
                self.kernel = block_step_kernel(scenario.inclusive,
                                                p.position_update == "new_heading", dim,
                                                vectorial)
            self.kernel_with_graph = step_kernel(*variant, True, dim, vectorial)
        self.track = p.tracks_linked(n, scenario.recording.observables)
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
            self.graph.parent, self.graph.deg, *self._neighbour_view(step),
        )
        self._advanced_for = step
        if with_graph:
            self._graph_for = step

    def _neighbour_view(self, step: int) -> tuple:
        """What the step kernel reads of the neighbourhoods: the grid (metric), or this
        step's k-NN lists (topological, searched once per step)."""
        if self.knn is None:
            return self.grid.view()
        if self._knn_for != step:
            self.knn.search(self.state["pos"], self.state.ids)
            self._knn_for = step
        return self.knn.view()

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
        if self.knn is not None:  # the union of the k-NN graphs (weakly connected)
            self._neighbour_view(step)
            self.knn.union_edges(st.ids, self.parent_u, by_id=True)
        else:
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

    def save(self) -> dict[str, np.ndarray]:
        """The sorted state with its ids, and Theorem 2's tracking: the forest of the
        union of the graphs since the last interval closed, and its counters."""
        out = self.state.save()
        if self.track:
            out["linked/parent"] = self.parent_u.to_numpy()
            out["linked/counts"] = np.array([self.linked[k] for k in LINKED], np.int64)
        return out

    def load(self, state: Mapping[str, np.ndarray]) -> None:
        """Back from `save`. The next state an observation computed ahead is forgotten:
        the step recomputes it, to the same bits (the visit with the graph and without
        give the same state)."""
        self.state.load(state)
        if self.track:
            put(self.parent_u, "linked/parent", state["linked/parent"])
            self.linked = dict(zip(LINKED, (int(v) for v in state["linked/counts"]),
                                   strict=True))
        self._advanced_for = self._graph_for = -1

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
