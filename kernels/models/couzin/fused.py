"""Couzin's model on the small-N path: many steps of many replicas in one kernel launch.

The equations are law.py's; only the schedule differs from step.py's (as in
kernels/models/cucker_smale/fused.py): one launch advances every replica of a batch
through a window of steps, replicas in parallel (one per CPU task), each replica's steps
and agents serial inside, the state kept in the kernel's arrays and the observables
written into a per-replica buffer. A replica computes the same numbers alone, in a batch,
or cut into any windows.

Per replica and step s (state (x, e) in agent-id order):
  1. on an observation step, polarization and milling of (x, e);
  2. every agent's zone sums over every other agent in id order (law.zone_term: the
     zones are tested pair by pair, at this N cheaper than a cell list, and the same
     model; the per-step schedule sums in grid order, so other bits), its noise (streams
     0-2 at (seed, s, id)), turn and move into the spare arrays: all from the state at s;
  3. the spare arrays become the state. A non-finite value stops the replica and
     records the step.
Covered up to FUSED_MAX_N agents (above it one replica's N^2 serial pairs outweigh the
per-step schedule's launches).
"""

from functools import cache

import numpy as np
import taichi as ti

from flocklab.schemas import Scenario

from ...space import rng
from ...space.cells import SPREAD
from ...space.frame import point_mass_frame
from ...space.integrate import nonfinite
from ...space.replica_loop import LoopBatch, make_replica, vector_rows
from . import law
from .start import directions

nd = ti.types.ndarray()
FUSED_MAX_N = 512
OBS = ("step", "polarization", "milling")
ARRAYS = ("aoff", "ooff", "prm", "iprm", "kseed", "pos", "ew", "pos2", "ew2", "obs")


@cache
def advance_kernel(dim: int):
    """The batch's kernel for one dimension."""
    vnd = vector_rows(dim)

    @ti.func
    def observe(b, s, r, a0, n, q, A: ti.template()):
        """Row r of observables: replica b's state at step s (observe.py's)."""
        pos, ew, obs = ti.static(A[5], A[6], A[9])
        c = ti.Vector.zero(float, dim)
        p = ti.Vector.zero(float, dim)
        for i in range(a0, a0 + n):
            c += pos[i]
            p += ew[i]
        c /= n
        m = ti.Vector.zero(float, 3)
        for i in range(a0, a0 + n):
            u = pos[i] - c
            nu = u.norm()
            if nu > 0.0:
                u /= nu
                if ti.static(dim == 2):
                    m[2] += u[0] * ew[i][1] - u[1] * ew[i][0]
                else:
                    m += u.cross(ew[i])
        obs[r, 0] = s
        obs[r, 1] = p.norm() / n
        obs[r, 2] = m.norm() / n

    @ti.func
    def move(b, s, a0, n, q, A: ti.template()):
        """One step of the replica's agents; 1 if a value is not finite."""
        kseed, pos, ew, pos2, ew2 = ti.static(A[4], A[5], A[6], A[7], A[8])
        keys = ti.Vector([rng._mix(kseed[b, c] ^ rng._mix(ti.cast(s, ti.u32)))
                          for c in ti.static(range(law.STREAMS))], dt=ti.u32)
        bad = 0
        for i in range(a0, a0 + n):
            xi = pos[i]
            ei = ew[i]
            acc = law.zero_acc(dim)
            for k in range(a0, a0 + n):
                acc = law.zone_term(acc, pos[k] - xi, ew[k], ei, q)
            x, e = law.agent_step(xi, ei, acc, i - a0, keys, q)
            pos2[i] = x
            ew2[i] = e
            bad |= nonfinite(x, e)
        for i in range(a0, a0 + n):
            pos[i] = pos2[i]
            ew[i] = ew2[i]
        return bad

    replica = make_replica(observe, move, law.P.size)

    @ti.kernel
    def advance(s0: ti.i32, s1: ti.i32, aoff: nd, ooff: nd, prm: nd, iprm: nd, kseed: nd,
                pos: vnd, ew: vnd, pos2: vnd, ew2: vnd, obs: nd):
        A = ti.static((aoff, ooff, prm, iprm, kseed, pos, ew, pos2, ew2, obs))
        for t in range((aoff.shape[0] - 1) * SPREAD):
            if t % SPREAD == 0:  # one replica per CPU task
                replica(t // SPREAD, s0, s1, aoff, ooff, prm, iprm, A)

    return advance


class CouzinBatch(LoopBatch):
    """A batch of Couzin replicas (any N up to FUSED_MAX_N, parameters, seeds and steps
    each; one dimension)."""

    ARRAYS, OBS = ARRAYS, OBS
    DIVERGED = ("position/direction", law.DIVERGED_CAUSE)

    def __init__(self, scenarios: list[Scenario]):
        self.dim = dim = scenarios[0].dimension
        self.kernel = advance_kernel(dim)
        iprm = self.lay_out(scenarios)
        total = int(self.aoff[-1])
        B = len(scenarios)
        prm = np.zeros((B, law.P.size))
        kseed = np.zeros((B, law.STREAMS), dtype=np.uint32)
        pos, ew = np.zeros((total, dim)), np.zeros((total, dim))
        for b, sc in enumerate(scenarios):
            prm[b] = law.parameters(sc.model, sc.time.dt)
            kseed[b] = [rng.seed_key(sc.seed, c) for c in range(law.STREAMS)]
            a0, a1 = self.aoff[b], self.aoff[b + 1]
            pos[a0:a1], ew[a0:a1] = directions(sc)
        self.speed = np.repeat([sc.model.speed for sc in scenarios],
                               [s.n_agents for s in scenarios])

        arr = self.arr
        self.args = dict(
            aoff=arr(self.aoff, np.int32), ooff=arr(self.ooff, np.int32), prm=arr(prm),
            iprm=arr(iprm, np.int32), kseed=arr(kseed, np.uint32), pos=arr(pos),
            ew=arr(ew), pos2=arr(np.zeros((total, dim))), ew2=arr(np.zeros((total, dim))),
            obs=arr(np.zeros((int(self.ooff[-1]), len(OBS)))),
        )
        assert tuple(self.args) == ARRAYS

    def observables(self, b: int, iprm: np.ndarray) -> dict[str, np.ndarray]:
        """The per-step path's observables, of those replica b's recording names."""
        rows = self.rows(b, iprm)
        wants = self.scenarios[b].recording.wants
        keep = [c for c in OBS[1:] if wants(c)]
        return {"step": rows[:, 0], **{c: rows[:, OBS.index(c)] for c in keep}}

    def frame(self, b: int, arrays: list[str], step: int) -> dict[str, np.ndarray]:
        a0, a1 = self.aoff[b], self.aoff[b + 1]
        return point_mass_frame(lambda: self.host("pos")[a0:a1],
                                lambda: self.speed[a0:a1, None] * self.host("ew")[a0:a1],
                                arrays, self.dim, direction=lambda: self.host("ew")[a0:a1])

    @staticmethod
    def batch_key(scenario: Scenario) -> tuple | None:
        """Scenarios with the same key share a launch; None (the per-step path) above
        FUSED_MAX_N agents."""
        if scenario.n_agents > FUSED_MAX_N:
            return None
        return ("couzin", scenario.dimension)
