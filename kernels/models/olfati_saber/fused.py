"""Olfati-Saber on the small-N path: many steps of many replicas in one kernel launch.

The equations are law.py's; only the schedule differs from step.py's (as in
kernels/models/cucker_smale/fused.py): one launch advances every replica of a batch through
a window of steps, replicas in parallel (one per CPU task), each replica's steps and agents
serial inside, the state kept in the kernel's arrays and the observables written into a
per-replica buffer. A replica computes the same numbers alone, in a batch, or cut into any
windows.

Per replica and step s (state (q, p) in agent-id order, t = s dt):
  1. on an observation step, the quality measures of (q, p) (observe.py's definitions):
     every pair once for the deviation energy and the graph's union-find (components),
     the means, the mismatch, the cohesion radius, the nearest obstacle, the leader;
  2. the alpha sums over every pair once (law.mutual_term: agent j's term is agent i's
     negated; the per-step schedule's per-agent sums add in another order, so other bits)
     with law.py's range test pair by pair (at this N cheaper than a cell list, and the
     same model); then each agent's gamma and beta terms (law.acceleration);
  3. semi-implicit Euler. A non-finite value stops the replica and records the step.
Covered up to FUSED_MAX_N agents: one thread measured 52x faster than the per-step
schedule at N = 100 and 0.9x at N = 1000 (bench/small_n_olfati_saber.py), so `auto` leaves
N = 1000 to the per-step schedule.
"""

from functools import cache

import numpy as np
import taichi as ti

from flocklab.schemas import Scenario

from ...space.cells import SPREAD
from ...space.graph import find_serial, union_serial
from ...space.integrate import put_pair
from ...space.replica_loop import LoopBatch, make_replica, offsets, vector_rows
from . import law
from .observe import deviation_energy, relative_connectivity

nd = ti.types.ndarray()
FUSED_MAX_N = 512
OBS = ("step", "deviation_energy", "relative_connectivity", "velocity_mismatch",
       "cohesion_radius", "min_obstacle_distance", "leader_distance", "mean_velocity_x",
       "mean_velocity_y", "mean_velocity_z", "edges", "energy_sum", "components")
ARRAYS = ("aoff", "ooff", "koff", "prm", "iprm", "pos", "vel", "acc", "obs", "parent",
          "obst")


@cache
def advance_kernel(dim: int, alg: int):
    """The batch's kernel for one dimension and algorithm."""
    vnd = vector_rows(dim)

    @ti.func
    def observe(b, s, r, a0, n, q, A: ti.template()):
        """Row r of observables: replica b's state at step s (the host finishes the
        deviation energy and the connectivity from the edge sums and components)."""
        koff, pos, vel, obs, parent, obst = ti.static(A[2], A[5], A[6], A[8], A[9], A[10])
        energy = 0.0
        edges = 0.0
        vmean = ti.Vector.zero(float, dim)
        qmean = ti.Vector.zero(float, dim)
        for i in range(a0, a0 + n):
            parent[i] = i
        for i in range(a0, a0 + n):
            xi = pos[i]
            vmean += vel[i]
            qmean += xi
            for k in range(i + 1, a0 + n):
                e = law.edge(pos[k] - xi, q)
                energy += e[0]
                edges += e[1]
                if e[1] > 0.0:
                    union_serial(parent, i, k)
        vmean /= n
        qmean /= n
        mismatch = 0.0
        radius = 0.0
        gap = ti.math.inf
        roots = 0
        for i in range(a0, a0 + n):
            dv = vel[i] - vmean
            mismatch += dv.dot(dv)
            dq = pos[i] - qmean
            radius = ti.max(radius, dq.dot(dq))
            gap = ti.min(gap, law.obstacle_distance(pos[i], vel[i], obst, koff[b],
                                                    koff[b + 1]))
            if find_serial(parent, i) == i:
                roots += 1
        qr, _ = law.leader(q, ti.cast(s, float) * q[law.P.DT], dim)
        obs[r, 0] = s
        obs[r, 3] = 0.5 * mismatch
        obs[r, 4] = ti.sqrt(radius)
        obs[r, 5] = gap
        obs[r, 6] = (qmean - qr).norm()
        for c in ti.static(range(dim)):
            obs[r, 7 + c] = vmean[c]
        obs[r, 10] = edges
        obs[r, 11] = energy
        obs[r, 12] = roots

    @ti.func
    def move(b, s, a0, n, q, A: ti.template()):
        """One step of the replica's agents; 1 if a value is not finite."""
        koff, pos, vel, acc, obst = ti.static(A[2], A[5], A[6], A[7], A[10])
        h = q[law.P.DT]
        t = ti.cast(s, float) * h
        bad = 0
        for i in range(a0, a0 + n):
            acc[i] = ti.Vector.zero(float, dim)
        for i in range(a0, a0 + n):
            xi = pos[i]
            vi = vel[i]
            ai = ti.Vector.zero(float, dim)
            for k in range(i + 1, a0 + n):
                m = law.mutual_term(pos[k] - xi, vel[k], vi, q)
                ai += m
                acc[k] -= m
            acc[i] += ai
        for i in range(a0, a0 + n):
            u = law.acceleration(acc[i], pos[i], vel[i], t, q, obst, koff[b], koff[b + 1],
                                 alg)
            x, v = law.euler(pos[i], vel[i], u, h)
            bad |= put_pair(pos, vel, i, x, v)
        return bad

    replica = make_replica(observe, move, law.P.size)

    @ti.kernel
    def advance(s0: ti.i32, s1: ti.i32, aoff: nd, ooff: nd, koff: nd, prm: nd, iprm: nd,
                pos: vnd, vel: vnd, acc: vnd, obs: nd, parent: nd, obst: nd):
        A = ti.static((aoff, ooff, koff, prm, iprm, pos, vel, acc, obs, parent, obst))
        for t in range((aoff.shape[0] - 1) * SPREAD):
            if t % SPREAD == 0:  # one replica per CPU task
                replica(t // SPREAD, s0, s1, aoff, ooff, prm, iprm, A)

    return advance


class OlfatiSaberBatch(LoopBatch):
    """A batch of Olfati-Saber replicas (any N up to FUSED_MAX_N, parameters, obstacles
    and steps each; one dimension and algorithm)."""

    ARRAYS, OBS = ARRAYS, OBS
    DIVERGED = ("position/velocity", law.DIVERGED_CAUSE)
    CONVERGENCE = ("velocity_mismatch",)

    def __init__(self, scenarios: list[Scenario]):
        self.dim = dim = scenarios[0].dimension
        self.kernel = advance_kernel(dim, scenarios[0].model.algorithm)
        iprm = self.lay_out(scenarios)
        pos, vel = self.initial_rows()
        ks = [len(s.model.obstacles) for s in scenarios]
        koff = offsets(ks)
        obst = np.zeros((max(1, int(koff[-1])), law.OBST_WIDTH))
        total = int(self.aoff[-1])
        prm = np.zeros((len(scenarios), law.P.size))
        for b, sc in enumerate(scenarios):
            prm[b] = law.parameters(sc.model, sc.time.dt)
            if ks[b]:
                obst[koff[b]:koff[b + 1]] = law.obstacle_rows(sc.model)

        arr = self.arr
        self.args = dict(
            aoff=arr(self.aoff, np.int32), ooff=arr(self.ooff, np.int32),
            koff=arr(koff, np.int32), prm=arr(prm), iprm=arr(iprm, np.int32), pos=arr(pos),
            vel=arr(vel), acc=arr(np.zeros((total, dim))),
            obs=arr(np.zeros((int(self.ooff[-1]), len(OBS)))),
            parent=arr(np.zeros(total, np.int32), np.int32), obst=arr(obst),
        )
        assert tuple(self.args) == ARRAYS

    def observables(self, b: int, iprm: np.ndarray) -> dict[str, np.ndarray]:
        """The per-step path's observables, of those replica b's recording names."""
        sc = self.scenarios[b]
        rows = self.rows(b, iprm)
        n = sc.n_agents
        cols = {c: rows[:, OBS.index(c)] for c in OBS}
        cols["deviation_energy"] = deviation_energy(cols["energy_sum"], cols["edges"],
                                                    sc.model.d)
        cols["relative_connectivity"] = np.array(
            [relative_connectivity(n, int(c)) for c in cols["components"]])
        skip = {"step", "edges", "energy_sum", "components"}
        if not sc.model.obstacles:
            skip.add("min_obstacle_distance")
        if sc.model.algorithm == 1:
            skip.add("leader_distance")
        if self.dim == 2:
            skip.add("mean_velocity_z")
        wants = sc.recording.wants
        return {"step": rows[:, 0],
                **{c: cols[c] for c in OBS if c not in skip and wants(c)}}

    @staticmethod
    def batch_key(scenario: Scenario) -> tuple | None:
        """Scenarios with the same key share a launch; None (the per-step path) above
        FUSED_MAX_N agents."""
        if scenario.n_agents > FUSED_MAX_N:
            return None
        return ("olfati_saber", scenario.dimension, scenario.model.algorithm)
