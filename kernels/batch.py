"""The small-N path's driver: window after window of one fused launch per batch.

A batch (e.g. `VicsekBatch`) holds many replicas' state on the device and advances all of
them through a window of steps in one launch, writing the observables into a buffer. The
driver only picks the windows: each ends at the next frame to record, or after about
`WINDOW_SECONDS` of work (the first window is `WINDOW_AGENT_STEPS` agent-steps, later ones
are sized from the measured rate), so progress and cancellation are polled about ten times
a second. Window boundaries never change a bit of any replica.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import Any, Protocol

import numpy as np

from flocklab.schemas import Scenario

from .checks import run_checks
from .live import OBSERVATIONS_INTERVAL, ObservationFeed, ObservationsFn
from .result import FrameSink, RunResult

WINDOW_AGENT_STEPS = 100_000  # the first window: a few ms to tens of ms of work
WINDOW_SECONDS: float | None = 0.1  # later windows' target length (None: keep the first)


def host_array(a: np.ndarray, dtype: Any) -> np.ndarray:
    """`a` as a C-contiguous numpy array of `dtype` starting on a 64-byte line, for a fused
    kernel to run on in place (see FusedBatch). numpy aligns only to 16 bytes: rows of
    four doubles then straddle cache lines, which made the Vicsek kernel 10% slower."""
    dtype = np.dtype(dtype)
    nbytes = a.size * dtype.itemsize
    buf = np.empty(nbytes + 64, np.uint8)
    off = -buf.ctypes.data % 64
    out = buf[off:off + nbytes].view(dtype).reshape(a.shape)
    out[...] = a
    return out


class Snapshots:
    """A fused batch's snapshot buffer, for an observable the host computes (the flocking
    path's lambda_2, 3D F2's D3): at each observation the kernel writes `width` values per
    agent of each replica that takes them into its K rows (rows SNAP0 .. NOBS of the launch,
    from `base[b]`), and the host reads them after the launch. A window is cut into launches
    of at most `chunk` steps, so that K rows hold every observation of one, which never
    changes a bit; chunk is None when no replica takes snapshots (one launch a window)."""

    def __init__(self, ns: Sequence[int], rows: Sequence[int], on: Sequence[bool],
                 everies: Sequence[int], width: int, doubles: int):
        agents = sum(n for n, o in zip(ns, on, strict=True) if o)
        self.K = max(3, min(max(rows), doubles // max(width * agents, 1)))
        # a launch of chunk steps observes at most chunk / every + 2 rows (the last step)
        taking = [e for e, o in zip(everies, on, strict=True) if o]
        self.chunk = max(1, (self.K - 2) * min(taking)) if taking else None
        sizes = [self.K * width * n if o else 0 for n, o in zip(ns, on, strict=True)]
        self.base = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int32)
        self.ns, self.on, self.width = list(ns), list(on), width

    def launches(self, s0: int, s1: int) -> list[tuple[int, int]]:
        """The launches (a, b) of the window s0 .. s1."""
        step = s1 - s0 if self.chunk is None else self.chunk
        return [(a, min(a + step, s1)) for a in range(s0, s1, step)]

    def taken(self, snap: np.ndarray, first: np.ndarray, last: np.ndarray):
        """(b, r0, r1, values (r1 - r0, n, width)) for each replica that took rows r0 .. r1
        in the last launch (first, last: each replica's SNAP0 and NOBS slots)."""
        for b, on in enumerate(self.on):
            r0, r1 = int(first[b]), int(last[b])
            if on and r1 > r0:
                n = self.ns[b]
                vals = snap[self.base[b]:self.base[b] + (r1 - r0) * n * self.width]
                yield b, r0, r1, vals.reshape(r1 - r0, n, self.width)


class FusedBatch:
    """What every model's fused batch shares: its device arrays `args`, among them `iprm`,
    the per-replica integer slots whose slot 0 is the replica's last step; and host copies
    of the arrays, fetched once per window and shared by every replica's reader (copying a
    whole array per replica made reading a batch's results O(B^2): at 64 replicas, most of
    a sweep's system time).

    An array of `args` may be a numpy array (`host_array`) rather than a `ti.Ndarray`: the
    CPU backend runs the kernel on its memory in place, which spares the from/to-numpy
    kernels (each one's Python AST re-read and its code loaded at every process start) and
    a launch per read. Readers still get copies: a frame or a series handed out must not
    change under its holder when the next window runs."""

    args: dict[str, Any]
    STEPS = 0  # iprm slot of each replica's last step
    # Whether the kernel's threads take replicas from a queue, each the next one left (then
    # the driver hands them over largest first); else each CPU task runs one replica, and
    # the tasks go to the threads in contiguous blocks, so the driver keeps the input order
    # (largest first would give one thread all the large replicas).
    QUEUED = False
    dimensions: tuple[int, ...] = (2,)  # the values of space.dimension the kernel runs

    def end_at(self, step: int) -> None:
        """Make `step` every replica's last (cancellation): the next window observes it."""
        self.invalidate()
        held = self.args["iprm"]
        iprm = _copy(held)
        iprm[:, self.STEPS] = np.minimum(iprm[:, self.STEPS], step)
        if isinstance(held, np.ndarray):
            held[...] = iprm
        else:
            held.from_numpy(iprm)

    def status(self) -> np.ndarray:
        """Per-replica integer slots (steps, observation count, divergence step, ...)."""
        return _copy(self.args["iprm"])

    def host(self, name: str) -> np.ndarray:
        cache = self.__dict__.setdefault("_host_copies", {})
        if name not in cache:
            cache[name] = _copy(self.args[name])
        return cache[name]

    def invalidate(self) -> None:
        """Forget the copies: the device arrays are about to change."""
        self.__dict__.get("_host_copies", {}).clear()


def _copy(a: Any) -> np.ndarray:
    """A host copy of a batch's array (a numpy array or a `ti.Ndarray`)."""
    return a.copy() if isinstance(a, np.ndarray) else a.to_numpy()


class Batch(Protocol):
    """What a model's fused batch offers the driver (see kernels/models/vicsek/fused.py)."""

    scenarios: list[Scenario]

    def advance(self, s0: int, s1: int) -> None: ...
    def end_at(self, step: int) -> None: ...
    def status(self) -> np.ndarray: ...
    def observables(self, b: int, status: np.ndarray) -> dict[str, np.ndarray]: ...
    def frame(self, b: int, arrays: list[str]) -> dict[str, np.ndarray]: ...
    def convergence_keys(self) -> list[str]: ...
    def extra(self, b: int, status: np.ndarray) -> dict[str, Any]: ...
    def divergence(self, b: int, status: np.ndarray) -> tuple[int, str, str] | None: ...


def run_batch(
    make: Callable[[list[Scenario]], Batch],
    scenarios: Sequence[Scenario],
    *,
    backend: str,
    sinks: Sequence[FrameSink | None] | None = None,
    on_progress: Callable[[int, int], None] | None = None,
    should_stop: Callable[[], bool] | None = None,
    progress_interval: float = 0.2,
    on_observations: ObservationsFn | None = None,
    observations_interval: float = OBSERVATIONS_INTERVAL,
) -> list[RunResult]:
    """Run `scenarios` (one batch key) to the end, to cancellation or to blow-up.
    `on_observations` (a single scenario only) gets the rows the kernels have written so
    far, at window ends, batched as kernels/live.py says. Results in input order."""
    sinks = list(sinks) if sinks is not None else [None] * len(scenarios)
    # From a queue, the largest replicas first: every window then ends on a small one
    # instead of leaving one core alone with a large one. A replica's bits do not depend
    # on its place in the batch.
    order = list(range(len(scenarios)))
    if getattr(make, "QUEUED", False):
        order.sort(key=lambda b: -scenarios[b].n_agents)
    results = _run_ordered(make, [scenarios[b] for b in order], [sinks[b] for b in order],
                           backend, on_progress, should_stop, progress_interval,
                           on_observations, observations_interval)
    place = {b: j for j, b in enumerate(order)}
    return [results[place[b]] for b in range(len(scenarios))]


def _run_ordered(
    make: Callable[[list[Scenario]], Batch],
    scenarios: list[Scenario],
    sinks: list[FrameSink | None],
    backend: str,
    on_progress: Callable[[int, int], None] | None,
    should_stop: Callable[[], bool] | None,
    progress_interval: float,
    on_observations: ObservationsFn | None,
    observations_interval: float,
) -> list[RunResult]:
    """`run_batch` with the replicas in launch order."""
    from .engine import time_to_converge

    t0 = time.perf_counter()
    batch = make(scenarios)
    setup = time.perf_counter() - t0
    steps = [s.time.steps for s in scenarios]
    last = max(steps)
    agents = sum(s.n_agents for s in scenarios)
    window = max(1, WINDOW_AGENT_STEPS // max(agents, 1))
    frame_every = [s.recording.every if s.recording.enabled and sinks[b] is not None else 0
                   for b, s in enumerate(scenarios)]
    arrays = [[a for a in s.recording.arrays if a in type(s.model).state_arrays]
              for s in scenarios]

    def record(step: int, status: np.ndarray | None, last: bool = False) -> None:
        """Frames due at `step` (every k steps and at each replica's end; `last`: the
        stopping step of a cancelled run, unless its frame is already there)."""
        for b, sink in enumerate(sinks):
            k = frame_every[b]
            if not k or not arrays[b] or step > steps[b]:
                continue
            due = step == steps[b] or (step % k != 0 if last else step % k == 0)
            if due and (status is None or batch.divergence(b, status) is None):
                sink.frame(step, step * scenarios[b].time.dt, batch.frame(b, arrays[b]))

    # The batch's series are already the result's columns: nothing to filter.
    feed = (ObservationFeed(on_observations, None, observations_interval)
            if on_observations is not None and len(scenarios) == 1 else None)
    record(0, None)
    s, cancelled, last_progress = 0, False, time.perf_counter()
    while s <= last:
        nxt = min(s + window, last + 1)
        for b, k in enumerate(frame_every):  # stop at the next frame to record
            if k and s < steps[b]:
                nxt = min(nxt, (s // k + 1) * k, steps[b])
        started = time.perf_counter()
        batch.advance(s, nxt)
        took = time.perf_counter() - started
        if WINDOW_SECONDS is not None and nxt - s >= window and took > 0:
            window = max(1, min(8 * window, int(window * WINDOW_SECONDS / took)))
        s = nxt
        if any(frame_every):
            record(s, batch.status())
        if s > last:
            break
        now = time.perf_counter()
        if on_progress is not None and now - last_progress >= progress_interval:
            last_progress = now
            on_progress(min(s, last), last)
        if feed is not None and feed.due(now):
            feed.send(_series(batch, 0, batch.status(), scenarios[0]), now)
        if should_stop is not None and should_stop():
            cancelled = True
            batch.end_at(s)
            batch.advance(s, s + 1)  # the final observation at the stopping step
            if any(frame_every):
                record(s, batch.status(), last=True)
            break
    status = batch.status()
    wall = time.perf_counter() - t0
    results = []
    for b, sc in enumerate(scenarios):
        obs = _series(batch, b, status, sc)
        div = batch.divergence(b, status)
        done = min(s, steps[b]) if div is None else div[0]
        error = None
        if div is not None:
            step, quantity, cause = div
            error = {"step": step, "time": step * sc.time.dt, "quantity": quantity,
                     "cause": cause,
                     "message": f"step {step}: non-finite or runaway {quantity}; "
                                f"likely cause: {cause}"}
        state = "diverged" if div is not None else "cancelled" if cancelled and (
            done < steps[b]) else "completed"
        final = {k: float(v[-1]) for k, v in obs.items() if len(v)}
        tol = sc.convergence.tolerance
        convergence = {k: time_to_converge(obs["time"], obs[k], tol)
                       for k in batch.convergence_keys() if k in obs}
        results.append(RunResult(
            status=state, backend=backend, steps=done, wall_seconds=wall,
            n_agents=sc.n_agents, observables=obs, final=final, convergence=convergence,
            extra={"setup_seconds": setup, "engine_path": "fused",
                   **batch.extra(b, status), **run_checks(sc, obs)},
            error=error,
        ))
    if on_progress is not None and len(scenarios) == 1:
        on_progress(results[0].steps, steps[0])
    return results


def _series(batch: Batch, b: int, status: np.ndarray, sc: Scenario) -> dict[str, np.ndarray]:
    """Replica b's observables so far: float64 like the per-step path's series, whatever
    the kernels' precision, with `time` after `step`."""
    obs = {k: np.asarray(v, dtype=np.float64) for k, v in batch.observables(b, status).items()}
    return {"step": obs["step"], "time": obs["step"] * sc.time.dt,
            **{k: v for k, v in obs.items() if k != "step"}}
