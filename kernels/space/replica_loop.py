"""The fused small-N schedules' replica loop: one replica's steps, serially, inside one CPU
task (the families' fused.py supply only their law's observation and move).

`make_replica(observe, move, size)` gives `replica(b, s0, s1, aoff, ooff, prm, iprm, A)`:
replica b (agents aoff[b] .. aoff[b + 1], parameters prm[b, 0 .. size]) from step s0
towards s1, stopping at its last step iprm[b, IP.STEPS] or at a divergence. Per step s:
  1. on an observation step (s a multiple of iprm[b, IP.EVERY], or the last step), the
     next row r = ooff[b] + iprm[b, IP.NOBS] is taken and `observe(b, s, r, a0, n, q, A)`
     writes the observables of the state at s into it;
  2. before the last step, `move(b, s, a0, n, q, A)` advances the state to s + 1 and
     returns 1 if a value is not finite: the replica stops with s in iprm[b, IP.BAD].
`A` is the family's tuple of arrays, handed through to its functions untouched.

`LoopBatch` is the host side such a family's batch shares: the replicas' agent and
observation-row offsets and slots, the launch, the observation rows, the divergence.
"""

from collections.abc import Callable
from typing import Any

import numpy as np
import taichi as ti

from flocklab.schemas import Scenario

from .. import runtime
from ..replicas import FusedBatch, host_array
from .frame import point_mass_frame
from .params import Slots

# Each replica's integer slots: its last step, its observation interval, the step it
# diverged at (-1: none) and the observation rows written.
IP = Slots("STEPS", "EVERY", "BAD", "NOBS")


def offsets(counts: Any) -> np.ndarray:
    """[0, c_0, c_0 + c_1, ...] (int32): where each replica's rows of an array start."""
    return np.concatenate([[0], np.cumsum(counts)]).astype(np.int32)


def observation_rows(scenarios: list[Scenario]) -> list[int]:
    """Each replica's budget of observation rows: one per observation step, the last
    step's included, and one to spare."""
    return [s.time.steps // s.recording.observables_every + 2 for s in scenarios]


def cell_offsets(ns: list[int], per_agent: int) -> np.ndarray:
    """Where each replica's cells start in a per-replica cell list (replica_cells.py) of
    per_agent * n + 16 cells (the cell budget) and the one past its last."""
    return offsets([per_agent * n + 17 for n in ns])


def vector_rows(dim: int) -> Any:
    """The kernel argument type of a state's (N, dim) array as N dim-vectors: one load per
    row (kernels/space/grid.py `row`), 10% of the step at N = 100 next to a load per
    component."""
    return ti.types.ndarray(dtype=ti.types.vector(dim, float), ndim=1)


def make_replica(observe: Callable, move: Callable, size: int) -> Callable:
    """The replica loop over a family's `observe` and `move` (ti.func's), its parameter
    vector `size` values long."""

    @ti.func
    def replica(b, s0, s1, aoff: ti.template(), ooff: ti.template(), prm: ti.template(),
                iprm: ti.template(), A: ti.template()):
        """Replica b from step s0 towards s1 (serially: its steps, then its agents)."""
        a0 = aoff[b]
        n = aoff[b + 1] - a0
        q = ti.Vector([prm[b, c] for c in ti.static(range(size))], dt=float)
        s = s0
        while s < s1 and s <= iprm[b, IP.STEPS] and iprm[b, IP.BAD] < 0:
            steps = iprm[b, IP.STEPS]
            if s % iprm[b, IP.EVERY] == 0 or s == steps:
                r = ooff[b] + iprm[b, IP.NOBS]
                iprm[b, IP.NOBS] += 1
                observe(b, s, r, a0, n, q, A)
            if s < steps:
                if move(b, s, a0, n, q, A) != 0:
                    iprm[b, IP.BAD] = s
            s += 1

    return replica


class LoopBatch(FusedBatch):
    """A batch of replicas advanced by `make_replica`'s loop: `kernel(s0, s1, *arrays)`
    with the arrays of `args` in the order ARRAYS, observation rows of the columns OBS
    (column 0: the step) in `args["obs"]`, DIVERGED (what went non-finite, and why) for
    a divergence and CONVERGENCE, the observables a convergence test reads."""

    dimensions = (2, 3)
    CHECKPOINTS = True  # the whole state is in `args`
    ARRAYS: tuple[str, ...] = ()
    OBS: tuple[str, ...] = ()
    DIVERGED: tuple[str, str] = ("", "")
    CONVERGENCE: tuple[str, ...] = ()  # the observables a convergence test reads
    dim: int
    kernel: Callable[..., None]

    def lay_out(self, scenarios: list[Scenario]) -> np.ndarray:
        """Keep the scenarios and the offsets of each replica's agents (aoff) and
        observation rows (ooff: one per observation step, the last step's included);
        return the replicas' slots (IP), their steps and intervals filled in."""
        self.scenarios = scenarios
        self.aoff = offsets([s.n_agents for s in scenarios])
        self.ooff = offsets(observation_rows(scenarios))
        iprm = np.zeros((len(scenarios), IP.size), dtype=np.int32)
        for b, sc in enumerate(scenarios):
            iprm[b, [IP.STEPS, IP.EVERY, IP.BAD]] = [
                sc.time.steps, sc.recording.observables_every, -1]
        return iprm

    def initial_rows(self) -> tuple[np.ndarray, np.ndarray]:
        """Every replica's initial positions and velocities (initial.py), rows
        aoff[b] .. aoff[b + 1] replica b's."""
        from .initial import initial_state

        total = int(self.aoff[-1])
        pos, vel = np.zeros((total, self.dim)), np.zeros((total, self.dim))
        for b, sc in enumerate(self.scenarios):
            init = initial_state(sc)
            pos[self.aoff[b]:self.aoff[b + 1]] = init.positions
            vel[self.aoff[b]:self.aoff[b + 1]] = init.velocities
        return pos, vel

    @staticmethod
    def arr(a: np.ndarray, dtype: Any = float) -> np.ndarray:
        """a as an array the kernel runs on in place (FusedBatch: no from/to-numpy
        kernels), floats in the run's precision."""
        return host_array(a, runtime.real() if dtype is float else dtype)

    def advance(self, s0: int, s1: int) -> None:
        """Advance every replica from step s0 towards s1 (each stops at its own end)."""
        self.invalidate()
        self.kernel(s0, s1, *(self.args[k] for k in self.ARRAYS))

    def frame(self, b: int, arrays: list[str], step: int) -> dict[str, np.ndarray]:
        """A point mass's frame (frame.py) of the state `pos`, `vel` of `args`."""
        a0, a1 = self.aoff[b], self.aoff[b + 1]
        return point_mass_frame(lambda: self.host("pos")[a0:a1],
                                lambda: self.host("vel")[a0:a1], arrays, self.dim)

    def convergence_keys(self) -> list[str]:
        return list(self.CONVERGENCE)

    def rows(self, b: int, iprm: np.ndarray) -> np.ndarray:
        """Replica b's observation rows so far (float64)."""
        o0 = self.ooff[b]
        return self.host("obs")[o0:o0 + iprm[b, IP.NOBS]].astype(np.float64)

    def extra(self, b: int, iprm: np.ndarray) -> dict[str, Any]:
        return {}

    def divergence(self, b: int, iprm: np.ndarray) -> tuple[int, str, str] | None:
        step = int(iprm[b, IP.BAD])
        return None if step < 0 else (step, *self.DIVERGED)
