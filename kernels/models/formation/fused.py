"""M4 on the small-N path: many steps of many replicas in one kernel launch.

The equations are the ones `kernels/models/formation/kernel.py` documents (paper 003, eq. 1-6, 12):
  rdot_i = f(|l_i - r_i|) (l_i - r_i)/|l_i - r_i| + sum_{|r_ij| < d} g(|r_ji|) r_ji/|r_ji|,
  l_i = p(t) + b_i(t) (F1) or p(t) (F2), explicit Euler or classical RK4;
only the schedule differs. One launch advances every replica of a batch through a window
of steps: replicas in parallel (one per CPU task), each replica's steps and agents
serially inside, all pairs visited (N is small here), the state kept in the kernel's
arrays and the observables written into a per-replica buffer. The host comes back only at
frame, progress and cancellation points, which never changes a bit: a replica computes
the same numbers alone, in a batch, or cut into any windows.

The dimension (2 or 3) is a compile-time parameter of the kernels, as on the per-step path:
positions, p(t), q(t) and b_i(t) are dim-vectors, and 2D compiles to the arithmetic it had
before 3D (its bits unchanged); 3D adds `leader_z` and `centroid_z` to the observables.
F2's D3 in 3D is a linear program per component (`props.surrounds_3d`), the host's: at each
observation the kernel writes the replica's positions and component labels into a snapshot
buffer, and after each launch the host fills D3 from them with `props.d3_holds_3d` (as
the flocking family's lambda_2). A window is cut into launches of at most `chunk` steps
when the buffer cannot hold all of its observations, which never changes a bit.

The leader is evaluated inside the kernel at every step (and RK4 half step): a straight
path as p0 + q t until the arrival time, F1's schedule (rotations, morphs, smoothstep or
linear) from the stored formations and their dim x dim weights; a 3D rotation turns
about its change's axis (Rodrigues' formula, `shapes.rotation3`). A spline path's arc-length
timing is the host's (`path.SplineTable`, the per-step path's arc-length
inversion vectorised over t): p(t), and q(t) at observation steps, are tabulated for each
window (about 0.1 ms per step on the host, the fused path's largest cost for a spline).

Not on this path (`FormationBatch.batch_key` returns None, the per-step path runs them):
a run whose Euler step could enter the dense regime (9 N > `max_exact_candidates`: the
per-step path coarse-grains there), N above `MAX_N` (all pairs would cost more than the
per-step path's grid), and N = 1 (no pair for the minimum distance).

Here: the window kernel and the batch; the terms (f, g, leader, rdot_i, parameter slots)
are in `fused_terms`, the observables in `fused_observe`.
"""

from functools import cache
from typing import Any

import numpy as np
import taichi as ti

from flocklab.schemas import Scenario
from flocklab.schemas.formation import (
    FormationChange,
    FormationParams,
    QuadraticF,
    SaturatingF,
    SplinePath,
)

from ... import runtime
from ...checkpoint import put
from ...replicas import FusedBatch, Snapshots
from ...space.cells import SPREAD
from ...space.grid import row as row_of
from ...space.grid import runaway_cause, widen
from ...space.initial import initial_state
from ...space.replica_loop import observation_rows, offsets
from .forces import F_KINDS, G_KINDS
from .fused_observe import (
    COMMON,
    COMMON_3D,
    F1_OBS,
    F2_OBS,
    N_OBS,
    OBS,
    SNAP_WIDTH,
    observe,
)
from .fused_terms import (
    IP,
    P,
    is_nonfinite,
    leader_state,
    rate,
    runaway,
)
from .norms import norms
from .path import LeaderPath, SplineTable, StraightLine, make_path
from .props import d3_holds_3d
from .schedule import OffsetSchedule

nd = ti.types.ndarray()
CHANGE_COLS = 7  # chg's columns (_change_row)
MAX_N = 512  # all pairs up to here: at N = 1000 a fused F2 step cost as much CPU as a
# per-step one (4.3 vs 4.2 ms, the per-step path on 2 threads), at N = 500 1.3 vs 2.2 ms
SNAP_DOUBLES = 4_000_000  # snapshot buffer for 3D F2's D3 (32 MB), cut into launches above
# Why a replica stopped (iprm[IP.CAUSE]), as the per-step path words it: its step check
# (0, 1), or its grid's check of the positions it buckets (2, 3; kernels/space/grid.py), which
# runs first at every step and RK4 stage. Cause 3 is `runaway_cause` of prm[P.EXTENT].
CAUSES = (
    "two agents at the same position, where g is singular (dt too large lets agents jump "
    "onto each other)",
    "non-finite position (dt too large for the repulsion's stiffness at close range)",
    "a position became non-finite",
    "the swarm ran away",  # runaway_cause(extent)
)


@cache
def advance_kernel(rk4: bool, dim: int):
    """The window kernel and the frame-velocity kernel for one integrator and dimension
    (positions (N, dim); RK4's rates kk hold the four stages' dim columns side by side)."""

    @ti.kernel
    def advance(s0: ti.i32, s1: ti.i32, h0: ti.i32, aoff: nd, ooff: nd, prm: nd, iprm: nd,
                chg: nd, inforce: nd, forms: nd, lead: nd, pos: nd, ps: nd, kk: nd, y: nd,
                deg: nd, parent: nd, ang: nd, gmax: nd, gcnt: nd, obs: nd, snap: nd,
                sbase: nd):
        for t in range((aoff.shape[0] - 1) * SPREAD):
            if t % SPREAD == 0:  # one replica per CPU task
                b = t // SPREAD
                a0 = aoff[b]
                n = aoff[b + 1] - a0
                steps = iprm[b, IP.STEPS]
                every = iprm[b, IP.EVERY]
                dt = prm[b, P.DT]
                per = ti.static(2 if rk4 else 1)
                iprm[b, IP.SNAP0] = iprm[b, IP.NOBS]  # the snapshot buffer's row 0
                s = s0
                while s < s1 and s <= steps and iprm[b, IP.BAD] < 0:
                    h = s * per
                    if runaway(b, a0, n, pos, prm, iprm, dim) != 0:
                        iprm[b, IP.BAD] = s
                        break
                    if s % every == 0 or s == steps:
                        row = ooff[b] + iprm[b, IP.NOBS]
                        at = sbase[b] + (iprm[b, IP.NOBS] - iprm[b, IP.SNAP0]) * n * SNAP_WIDTH
                        iprm[b, IP.NOBS] = iprm[b, IP.NOBS] + 1
                        observe(b, a0, n, s, h, h0, row, prm, iprm, chg, inforce, lead,
                                 forms, pos, deg, parent, ang, gmax, gcnt, obs, snap, at,
                                 dim)
                    if s < steps:
                        coincident = 0
                        nonfinite = 0
                        lp, _q, ma, mb, ka, kb = leader_state(b, h, h0, prm, iprm, chg,
                                                               inforce, lead, dim)
                        if ti.static(not rk4):
                            for i in range(a0, a0 + n):
                                for c in ti.static(range(dim)):
                                    ps[i, c] = pos[i, c]
                            for i in range(a0, a0 + n):
                                r = rate(b, i, a0, n, ps, lp, ma, mb, ka, kb, prm, iprm,
                                          forms, dim)
                                x = ti.Vector.zero(float, dim)
                                for c in ti.static(range(dim)):
                                    x[c] = ps[i, c] + dt * r[c]
                                    pos[i, c] = x[c]
                                coincident |= ti.cast(r[dim] > 0.0, ti.i32)
                                nonfinite |= ti.cast(is_nonfinite(x, dim), ti.i32)
                        else:
                            # k1 at (x, t); k2, k3 at (x + dt/2 k, t + dt/2); k4 at
                            # (x + dt k3, t + dt): y holds each stage's positions.
                            for i in range(a0, a0 + n):
                                r = rate(b, i, a0, n, pos, lp, ma, mb, ka, kb, prm, iprm,
                                          forms, dim)
                                for c in ti.static(range(dim)):
                                    kk[i, c] = r[c]
                                coincident |= ti.cast(r[dim] > 0.0, ti.i32)
                                nonfinite |= ti.cast(is_nonfinite(r, dim), ti.i32)
                            stop = 0  # the stage grid's check stops the step at once
                            for stage in ti.static(range(1, 4)):
                                a = 0.5 * dt
                                if ti.static(stage == 3):
                                    a = dt
                                if stop == 0:
                                    for i in range(a0, a0 + n):
                                        for c in ti.static(range(dim)):
                                            y[i, c] = pos[i, c] + a * kk[i, dim * (stage - 1) + c]
                                    stop = runaway(b, a0, n, y, prm, iprm, dim)
                                if stop == 0:
                                    hp = h + 1
                                    if ti.static(stage == 3):
                                        hp = h + 2
                                    lq, _q2, mq, mr, kq, kr = leader_state(
                                        b, hp, h0, prm, iprm, chg, inforce, lead, dim)
                                    for i in range(a0, a0 + n):
                                        r = rate(b, i, a0, n, y, lq, mq, mr, kq, kr, prm,
                                                  iprm, forms, dim)
                                        for c in ti.static(range(dim)):
                                            kk[i, dim * stage + c] = r[c]
                                        coincident |= ti.cast(r[dim] > 0.0, ti.i32)
                                        nonfinite |= ti.cast(is_nonfinite(r, dim), ti.i32)
                            if stop != 0:
                                iprm[b, IP.BAD] = s
                                break
                            for i in range(a0, a0 + n):
                                for c in ti.static(range(dim)):
                                    pos[i, c] = pos[i, c] + dt / 6.0 * (
                                        kk[i, c] + 2.0 * kk[i, dim + c]
                                        + 2.0 * kk[i, 2 * dim + c] + kk[i, 3 * dim + c])
                                nonfinite |= ti.cast(is_nonfinite(row_of(pos, i, dim), dim),
                                                     ti.i32)
                        if coincident != 0 or nonfinite != 0:
                            iprm[b, IP.BAD] = s
                            iprm[b, IP.CAUSE] = ti.select(coincident != 0, 0, 1)
                    s += 1

    @ti.kernel
    def velocity(b: ti.i32, h: ti.i32, aoff: nd, prm: nd, iprm: nd, chg: nd, inforce: nd,
                 forms: nd, lead: nd, pos: nd, vel: nd):
        """rdot of replica b's agents at their current positions, time index h (a frame);
        lead's row 0 holds a spline leader's p(t)."""
        for _ in range(1):  # one serial task: the sums in the step's order
            a0 = aoff[b]
            n = aoff[b + 1] - a0
            lp, _q, ma, mb, ka, kb = leader_state(b, h, h, prm, iprm, chg, inforce, lead,
                                                  dim)
            for i in range(a0, a0 + n):
                r = rate(b, i, a0, n, pos, lp, ma, mb, ka, kb, prm, iprm, forms, dim)
                for c in ti.static(range(dim)):
                    vel[i, c] = r[c]

    return advance, velocity


class FormationBatch(FusedBatch):
    """The state of a batch of M4 replicas (any N <= MAX_N, design, gains, path, schedule,
    steps each; one integrator and dimension), advanced window by window by
    `advance_kernel`."""

    dimensions = (2, 3)

    def __init__(self, scenarios: list[Scenario]):
        self.scenarios = scenarios
        p0: FormationParams = scenarios[0].model  # type: ignore[assignment]
        self.per = 2 if p0.integrator == "rk4" else 1
        self.dim = dim = scenarios[0].dimension
        self.advance_k, self.velocity_k = advance_kernel(p0.integrator == "rk4", dim)
        ns = [s.n_agents for s in scenarios]
        self.aoff = offsets(ns)
        rows = observation_rows(scenarios)
        self.ooff = offsets(rows)
        B, total = len(scenarios), int(self.aoff[-1])
        prm = np.zeros((B, P.size))
        iprm = np.zeros((B, IP.size), dtype=np.int32)
        pos = np.zeros((total, dim))
        chg, inforce, forms = [], [], []
        self.paths, self.f1, self.snap = [], [], []
        for b, sc in enumerate(scenarios):
            p: FormationParams = sc.model  # type: ignore[assignment]
            n, d = sc.n_agents, sc.neighbours.radius
            init = initial_state(sc)
            path = make_path(p.path, init.positions.mean(axis=0))
            if isinstance(p.attraction, SaturatingF):  # as FormationKernel refuses it
                top = float(norms(path.velocity(0.0)))
                if top >= p.attraction.v_max:
                    raise ValueError(
                        f"leader speed {top:g} >= attraction.v_max = "
                        f"{p.attraction.v_max:g}: the agents could never keep up "
                        "(eq. 8 has no solution)")
            self.paths.append(path)
            f1 = p.design == "F1"
            self.f1.append(f1)
            # D3 in 3D: the host's (props.d3_holds_3d), from snapshots, when it is asked for.
            self.snap.append(dim == 3 and not f1 and sc.recording.wants("D3"))
            a0 = int(self.aoff[b])
            pos[a0:a0 + n] = init.positions
            prm[b, :] = self._params(sc, path)
            iprm[b, :] = [sc.time.steps, sc.recording.observables_every, -1, 0, 0,
                          F_KINDS[p.attraction.kind], G_KINDS[p.repulsion.kind], int(f1),
                          int(isinstance(p.path, SplinePath)), len(chg), len(p.schedule),
                          len(inforce), len(forms), int(self.snap[-1]), 0]
            if f1:
                sched = OffsetSchedule(p.formation, p.schedule, n, d, dim)
                chg.extend(_change_row(c, dim) for c in p.schedule)
                inforce.extend([k, *m.ravel()] for k, m in sched.in_force)
                forms.extend(row for k in sched.stored for row in k)
        self.steps = iprm[:, IP.STEPS].copy()
        sbase = self._snapshots(ns, rows)

        def arr(a, shape, dtype=float) -> ti.Ndarray:
            a = np.asarray(a, dtype=runtime.real() if dtype is float else np.int32)
            out = ti.ndarray(dtype, shape=shape if not a.size else a.shape)
            if a.size:
                out.from_numpy(a)
            return out

        i32 = ti.i32
        self.args = dict(
            aoff=arr(self.aoff, None, i32), ooff=arr(self.ooff, None, i32),
            prm=arr(prm, None), iprm=arr(iprm, None, i32), chg=arr(chg, (1, CHANGE_COLS)),
            inforce=arr(inforce, (1, 1 + dim * dim)), forms=arr(forms, (1, dim)),
            lead0=ti.ndarray(float, shape=(B, 1, 2 * dim)), pos=arr(pos, None),
            ps=ti.ndarray(float, shape=(total, dim)),
            kk=ti.ndarray(float, shape=(total if self.per == 2 else 1, 4 * dim)),
            y=ti.ndarray(float, shape=(total if self.per == 2 else 1, dim)),
            deg=ti.ndarray(i32, shape=total), parent=ti.ndarray(i32, shape=total),
            ang=ti.ndarray(float, shape=total), gmax=ti.ndarray(float, shape=total),
            gcnt=ti.ndarray(i32, shape=total),
            obs=arr(np.zeros((int(self.ooff[-1]), N_OBS)), None),
            vel=ti.ndarray(float, shape=(total, dim)),
            snap=ti.ndarray(float, shape=max(int(sbase[-1]), 1)), sbase=arr(sbase, None, i32),
        )
        self.splines = [b for b, sc in enumerate(scenarios)
                        if isinstance(sc.model.path, SplinePath)]
        self.tables = {b: SplineTable(self.paths[b]) for b in self.splines}
        self.tables_dev: dict[str, ti.Ndarray] = {}  # the spline tables' device copies
        self.last_p: dict[int, tuple[int, np.ndarray]] = {}  # b: (h, p) of the last row
        self.now = np.zeros(B, dtype=np.int64)  # each replica's current step

    # Checkpoints: `args` holds the kernel's whole state (positions, counters, observation
    # rows, scratch); the host keeps each replica's current step, its last step (end_at),
    # the last spline row and 3D F2's D3 rows, all saved here.
    CHECKPOINTS = True

    def save_host(self) -> dict[str, np.ndarray]:
        out = {"host/now": self.now.copy(), "host/steps": np.asarray(self.steps).copy()}
        for b, (h, p) in self.last_p.items():
            out[f"host/last_p/{b}"] = np.array([h, *p], np.float64)
        for b, rows in enumerate(self.d3):
            if self.snap[b]:
                out[f"host/d3/{b}"] = rows.copy()
        return out

    def load_host(self, state) -> None:
        self.now = state["host/now"].copy()
        self.steps = state["host/steps"].copy()
        self.last_p = {}
        for key in state:
            if key.startswith("host/last_p/"):
                row = state[key]
                self.last_p[int(key.rsplit("/", 1)[1])] = (int(row[0]), row[1:].copy())
        for b in range(len(self.scenarios)):
            if self.snap[b]:
                put(self.d3[b], f"host/d3/{b}", state[f"host/d3/{b}"])

    def _snapshots(self, ns: list[int], rows: list[int]) -> np.ndarray:
        """The snapshot buffer of 3D F2's D3 (`Snapshots`); each replica's first slot."""
        self.snaps = Snapshots(ns, rows, self.snap,
                               [sc.recording.observables_every for sc in self.scenarios],
                               SNAP_WIDTH, SNAP_DOUBLES)
        self.d3 = [np.zeros(r) for r in rows]
        return self.snaps.base

    def _params(self, sc: Scenario, path: LeaderPath) -> np.ndarray:
        """Replica `sc`'s row of prm (a spline's timing is the host's: its S, Q, E unused)."""
        p: FormationParams = sc.model  # type: ignore[assignment]
        f = p.attraction
        d, dt = sc.neighbours.radius, sc.time.dt
        row = P.pack(
            R2=runtime.next_above(d * d) if sc.inclusive else d * d, D=d, D2=d * d,
            KG=p.repulsion.k_g, FA=f.c if isinstance(f, QuadraticF) else f.k,
            FB=f.v_max if isinstance(f, SaturatingF) else 0.0, DT=dt, TSTEP=dt / self.per,
            COLLIDE=p.collision(d), TOL=p.at_leader(d),
            LAG_SIGN=-1.0 if p.lag_sign == "eq8" else 1.0, CELL=d * widen())
        if isinstance(path, StraightLine):
            row[P.T_ARR] = path.arrival_time
            for first, v in ((P.S, path.start), (P.Q, path.q), (P.E, path.end)):
                row[first:first + self.dim] = v
        return row

    def _lead_table(self, s0: int, s1: int) -> ti.Ndarray:
        """The spline leaders' p(t) for the window's time indices (and q(t) at the
        observation steps), from half-step index s0 * per on."""
        if not self.splines:
            return self.args["lead0"]  # read by spline replicas only
        h0 = s0 * self.per
        rows = (s1 - s0) * self.per + 1
        table = np.zeros((len(self.scenarios), rows, 2 * self.dim))
        for b in self.splines:
            sc = self.scenarios[b]
            steps, every = int(self.steps[b]), sc.recording.observables_every
            h = np.arange(h0, min(s1, steps) * self.per + 1)
            if not len(h):  # this replica has ended
                continue
            s, rem = np.divmod(h, self.per)
            seen = (rem == 0) & ((s % every == 0) | (s == steps))  # observation steps
            table[b, : len(h)] = self.tables[b].at(h * (sc.time.dt / self.per), seen)
            self.last_p[b] = (int(h[-1]), table[b, len(h) - 1, :self.dim].copy())
        return self._device("lead", table)

    def _device(self, name: str, a: np.ndarray) -> ti.Ndarray:
        """`a` in a reused device array (windows mostly share one shape; allocating a
        Taichi ndarray costs more than the copy). Kept out of `args`: it is rewritten
        before every read, so a checkpoint need not hold it."""
        held = self.tables_dev.get(name)
        if held is None or held.shape != a.shape:
            held = self.tables_dev[name] = ti.ndarray(float, shape=a.shape)
        held.from_numpy(runtime.as_real(a))
        return held

    def advance(self, s0: int, s1: int) -> None:
        """Advance every replica from step s0 towards s1 (each stops at its own end), in
        launches of at most `chunk` steps while D3 snapshots are taken."""
        self.invalidate()
        for c0, c1 in self.snaps.launches(s0, s1):
            self._launch(c0, c1)
            if self.snaps.chunk is not None:
                self._d3()
        self.now = np.minimum(s1, self.steps)

    def _launch(self, s0: int, s1: int) -> None:
        """One kernel launch: every replica from step s0 towards s1."""
        a = self.args
        self.advance_k(s0, s1, s0 * self.per, a["aoff"], a["ooff"], a["prm"], a["iprm"],
                       a["chg"], a["inforce"], a["forms"], self._lead_table(s0, s1),
                       a["pos"], a["ps"], a["kk"], a["y"], a["deg"], a["parent"], a["ang"],
                       a["gmax"], a["gcnt"], a["obs"], a["snap"], a["sbase"])

    def _d3(self) -> None:
        """D3 of the observations the last launch took (rows SNAP0 .. NOBS) of each 3D F2
        replica, from its snapshots with the per-step path's LP (props.d3_holds_3d); r_0 is
        the row's leader position, the kernel's p(t)."""
        iprm = self.status()
        snap, obs = self.args["snap"].to_numpy(), self.args["obs"].to_numpy()
        lead = [OBS.index(c) for c in ("leader_x", "leader_y", "leader_z")]
        for b, r0, r1, s in self.snaps.taken(snap, iprm[:, IP.SNAP0], iprm[:, IP.NOBS]):
            sc = self.scenarios[b]
            p = obs[self.ooff[b] + r0:self.ooff[b] + r1][:, lead]
            tol = sc.model.at_leader(sc.neighbours.radius)
            for r in range(r1 - r0):
                self.d3[b][r0 + r] = d3_holds_3d(s[r, :, :3] - p[r], s[r, :, 3].astype(int),
                                                 tol)

    def end_at(self, step: int) -> None:
        super().end_at(step)
        self.steps = np.minimum(self.steps, step)  # the host's copy of iprm[:, IP.STEPS]

    def observables(self, b: int, iprm: np.ndarray) -> dict[str, np.ndarray]:
        o0 = self.ooff[b]
        rows = self.host("obs")[o0:o0 + iprm[b, IP.NOBS]]
        keep = COMMON + (COMMON_3D if self.dim == 3 else ()) + (
            F1_OBS if self.f1[b] else F2_OBS)
        wants = self.scenarios[b].recording.wants
        out = {"step": rows[:, 0], **{c: rows[:, OBS.index(c)] for c in keep if wants(c)}}
        if self.snap[b]:
            out["D3"] = self.d3[b][:len(rows)].copy()
        return out

    def frame(self, b: int, arrays: list[str], step: int) -> dict[str, np.ndarray]:
        a0, a1 = self.aoff[b], self.aoff[b + 1]
        a = self.args
        out = {}
        if "position" in arrays:
            out["position"] = self.host("pos")[a0:a1]
        if "velocity" in arrays:
            h = int(self.now[b]) * self.per
            table = a["lead0"]
            if b in self.splines:  # p(t) of the state: the last window's last row
                at, p = self.last_p.get(b, (-1, None))
                if at != h:
                    t = np.array([h * (self.scenarios[b].time.dt / self.per)])
                    p = self.tables[b].at(t, np.zeros(1, dtype=bool))[0, :self.dim]
                lead = np.zeros((len(self.scenarios), 1, 2 * self.dim))
                lead[b, 0, :self.dim] = p
                table = self._device("frame_lead", lead)
            self.velocity_k(b, h, a["aoff"], a["prm"], a["iprm"], a["chg"], a["inforce"],
                            a["forms"], table, a["pos"], a["vel"])
            out["velocity"] = a["vel"].to_numpy()[a0:a1]  # just computed for replica b
        return out

    def convergence_keys(self) -> list[str]:
        return ["formation_error", "velocity_mismatch_max"]

    def extra(self, b: int, iprm: np.ndarray) -> dict[str, Any]:
        return {"leader_arrival_time": self.paths[b].arrival_time,
                "dense_regime": {"steps": 0, "max_reach": 1}}

    def divergence(self, b: int, iprm: np.ndarray) -> tuple[int, str, str] | None:
        step = int(iprm[b, IP.BAD])
        if step < 0:
            return None
        cause = CAUSES[iprm[b, IP.CAUSE]]
        if iprm[b, IP.CAUSE] == 3:
            cause = runaway_cause(float(self.args["prm"].to_numpy()[b, P.EXTENT]), self.dim)
        return step, "position", cause

    @staticmethod
    def batch_key(scenario: Scenario) -> tuple | None:
        """Scenarios with the same key share a launch; None: not for this path (see the
        module docstring)."""
        p: FormationParams = scenario.model  # type: ignore[assignment]
        n, dim = scenario.n_agents, scenario.dimension
        cap = p.max_exact_candidates
        if n < 2 or n > MAX_N or (p.integrator == "euler" and cap is not None
                                  and 9 * n > cap):
            return None
        return ("formation", p.integrator, dim)


def _change_row(c: FormationChange, dim: int) -> list[float]:
    """A change's row of chg: start, end, the angle (NaN: a morph), linear (1) or
    smoothstep (0), and in 3D the rotation's unit axis (default z; shapes.rotation3)."""
    axis = np.zeros(3)
    if dim == 3 and c.rotate is not None:
        axis = np.asarray(c.axis or (0.0, 0.0, 1.0), dtype=np.float64)
        axis = axis / np.linalg.norm(axis)
    return [c.start, c.end, np.nan if c.rotate is None else c.rotate,
            float(c.relaxation == "linear"), *axis]
