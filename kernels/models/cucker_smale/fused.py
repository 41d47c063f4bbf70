"""Cucker–Smale on the small-N path: many steps of many replicas in one kernel launch.

The equations are law.py's; only the schedule differs from step.py's (as in
kernels/models/vicsek/fused.py): one launch advances every replica of a batch through a
window of steps, replicas in parallel (one per CPU task), each replica's steps and agents
serial inside, the state kept in the kernel's arrays and the observables written into a
per-replica buffer. A replica computes the same numbers alone, in a batch, or cut into any
windows.

Per replica and step s (state (x, v) in agent-id order):
  1. on an observation step, the observables of (x, v): both diameters over every pair,
     the mean velocity and the velocity variance;
  2. u_i over every agent j, each pair once (psi is symmetric: half the weights of the
     per-step schedule's per-agent sums, which sum in another order, so other bits); a
     cutoff is law.py's weight test, pair by pair (at this N cheaper than a cell list, and
     the same model);
  3. semi-implicit Euler, or RK4 by integrate.py's stage_pair / finish_pair. A
     non-finite value stops the replica and records the step.
Covered up to FUSED_MAX_N agents (above it one replica's N^2 serial pairs outweigh the
per-step schedule's launches).
"""

from functools import cache

import numpy as np
import taichi as ti

from flocklab.schemas import Scenario

from ...space.cells import SPREAD
from ...space.integrate import STAGES, finish_pair, put_pair, stage_pair
from ...space.replica_loop import LoopBatch, make_replica, vector_rows
from . import law

nd = ti.types.ndarray()
FUSED_MAX_N = 1024
OBS = ("step", "velocity_diameter", "position_diameter", "mean_velocity_x",
       "mean_velocity_y", "mean_velocity_z", "velocity_variance")
ARRAYS = ("aoff", "ooff", "prm", "iprm", "pos", "vel", "acc", "xs", "vs", "xk", "vk", "obs",
          "den")


@cache
def advance_kernel(dim: int, local: bool, rk4: bool, cut: bool):
    """The batch's kernel for one dimension, normalisation kind, integrator and whether
    the replicas have a cutoff."""
    vnd = vector_rows(dim)

    @ti.func
    def accel(a0, n, q, xsrc: ti.template(), vsrc: ti.template(), out: ti.template(),
              den: ti.template()):
        """u_i of every agent of the replica (rows a0 .. a0 + n) at (xsrc, vsrc) into out:
        each pair once (law.mutual_term), added to i and subtracted from j."""
        for i in range(a0, a0 + n):
            out[i] = ti.Vector.zero(float, dim)
            if ti.static(local):
                den[i] = law.weight(0.0, q)  # i's own weight in its D (a zero term in S)
        for i in range(a0, a0 + n):
            xi = xsrc[i]
            vi = vsrc[i]
            ai = ti.Vector.zero(float, dim)
            di = 0.0
            for k in range(i + 1, a0 + n):
                w, t = law.mutual_term(xsrc[k] - xi, vsrc[k], vi, q, cut)
                ai += t
                out[k] -= t
                if ti.static(local):  # mean and sum need no D_i
                    di += w
                    den[k] += w
            out[i] += ai
            if ti.static(local):
                den[i] += di
        for i in range(a0, a0 + n):
            o = out[i]
            d = den[i] if ti.static(local) else 0.0
            out[i] = law.acceleration(ti.Vector([o[c] for c in ti.static(range(dim))] + [d]),
                                      q, local)

    @ti.func
    def observe(b, s, r, a0, n, q, A: ti.template()):
        """Row r of observables: replica b's state at step s."""
        pos, vel, obs = ti.static(A[4], A[5], A[11])
        d2 = ti.math.vec2(0.0, 0.0)
        mean = ti.Vector.zero(float, dim)
        for i in range(a0, a0 + n):
            vi = vel[i]
            xi = pos[i]
            mean += vi
            for k in range(i + 1, a0 + n):
                d2 = law.spread(d2, vi, vel[k], xi, pos[k])
        mean /= n
        var = 0.0
        for i in range(a0, a0 + n):
            d = vel[i] - mean
            var += d.dot(d)
        obs[r, 0] = s
        obs[r, 1] = ti.sqrt(d2[0])
        obs[r, 2] = ti.sqrt(d2[1])
        for c in ti.static(range(dim)):
            obs[r, 3 + c] = mean[c]
        obs[r, 6] = var / n

    @ti.func
    def move(b, s, a0, n, q, A: ti.template()):
        """One step of the replica's agents; 1 if a value is not finite."""
        pos, vel, acc, xs, vs, xk, vk, den = ti.static(A[4], A[5], A[6], A[7], A[8], A[9],
                                                       A[10], A[12])
        h = q[law.P.DT]
        bad = 0
        accel(a0, n, q, pos, vel, acc, den)
        if ti.static(rk4):
            for i in range(a0, a0 + n):
                xs[i] = pos[i]
                xk[i] = ti.Vector.zero(float, dim)
                vs[i] = vel[i]
                vk[i] = ti.Vector.zero(float, dim)
            for t in ti.static(range(3)):
                w = ti.static(STAGES[t][0])
                c = h * ti.static(STAGES[t][1])
                for i in range(a0, a0 + n):
                    xs[i], vs[i], xk[i], vk[i] = stage_pair(pos[i], vel[i], vs[i], acc[i],
                                                            xk[i], vk[i], w, c)
                accel(a0, n, q, xs, vs, acc, den)
            h6 = h / 6
            for i in range(a0, a0 + n):
                x, v = finish_pair(pos[i], vel[i], vs[i], acc[i], xk[i], vk[i], h6)
                bad |= put_pair(pos, vel, i, x, v)
        else:
            for i in range(a0, a0 + n):
                x, v = law.euler(pos[i], vel[i], acc[i], h)
                bad |= put_pair(pos, vel, i, x, v)
        return bad

    replica = make_replica(observe, move, law.P.size)

    @ti.kernel
    def advance(s0: ti.i32, s1: ti.i32, aoff: nd, ooff: nd, prm: nd, iprm: nd, pos: vnd,
                vel: vnd, acc: vnd, xs: vnd, vs: vnd, xk: vnd, vk: vnd, obs: nd, den: nd):
        A = ti.static((aoff, ooff, prm, iprm, pos, vel, acc, xs, vs, xk, vk, obs, den))
        for t in range((aoff.shape[0] - 1) * SPREAD):
            if t % SPREAD == 0:  # one replica per CPU task
                replica(t // SPREAD, s0, s1, aoff, ooff, prm, iprm, A)

    return advance


class CuckerSmaleBatch(LoopBatch):
    """A batch of Cucker–Smale replicas (any N up to FUSED_MAX_N, parameters and steps
    each; one dimension, integrator and normalisation kind)."""

    ARRAYS, OBS = ARRAYS, OBS
    DIVERGED = ("position/velocity", law.DIVERGED_CAUSE)
    CONVERGENCE = ("velocity_diameter",)

    def __init__(self, scenarios: list[Scenario]):
        first = scenarios[0]
        self.dim = dim = first.dimension
        rk4 = first.model.integrator == "rk4"
        self.kernel = advance_kernel(dim, first.model.normalization == "local", rk4,
                                     first.model.cutoff is not None)
        iprm = self.lay_out(scenarios)
        pos, vel = self.initial_rows()
        total = int(self.aoff[-1])
        prm = np.zeros((len(scenarios), law.P.size))
        for b, sc in enumerate(scenarios):
            prm[b] = law.parameters(sc.model, sc.n_agents, sc.time.dt)

        arr = self.arr
        stage = (total, dim) if rk4 else (1, dim)
        self.args = dict(
            aoff=arr(self.aoff, np.int32), ooff=arr(self.ooff, np.int32), prm=arr(prm),
            iprm=arr(iprm, np.int32), pos=arr(pos), vel=arr(vel),
            acc=arr(np.zeros((total, dim))), xs=arr(np.zeros(stage)),
            vs=arr(np.zeros(stage)), xk=arr(np.zeros(stage)), vk=arr(np.zeros(stage)),
            obs=arr(np.zeros((int(self.ooff[-1]), len(OBS)))), den=arr(np.zeros(total)),
        )
        assert tuple(self.args) == ARRAYS

    def observables(self, b: int, iprm: np.ndarray) -> dict[str, np.ndarray]:
        """The per-step path's observables, of those replica b's recording names."""
        rows = self.rows(b, iprm)
        wants = self.scenarios[b].recording.wants
        keep = [c for c in OBS[1:] if wants(c) and not (c.endswith("_z") and self.dim == 2)]
        return {"step": rows[:, 0], **{c: rows[:, OBS.index(c)] for c in keep}}

    @staticmethod
    def batch_key(scenario: Scenario) -> tuple | None:
        """Scenarios with the same key share a launch; None (the per-step path) above
        FUSED_MAX_N agents."""
        p = scenario.model
        if scenario.n_agents > FUSED_MAX_N:
            return None
        return ("cucker_smale", scenario.dimension, p.normalization == "local", p.integrator,
                p.cutoff is not None)
