"""The one driver: window after window of `Replicas.advance`, for every schedule.

It observes nothing itself: the schedule observes inside `advance` (kernels/replicas.py).
The driver picks the windows, each ending at the next frame to record or after about
`WINDOW_SECONDS` of work (the first window is `WINDOW_AGENT_STEPS` agent-steps, or the
schedule's `FIRST_WINDOW`; later ones are sized from the measured rate), so progress, live
observations and cancellation are polled about ten times a second. A run with checkpoints
(`recording.checkpoint_every`, `checkpoint_seconds`, and a caller's `on_checkpoint`) also
ends a window at every k-th step, and hands the schedule's saved state over at a window's
end when k steps or the seconds are up; `resume` starts from such a state. It records the frames
and assembles each replica's `RunResult` (status, divergence, convergence times, the
papers' checks). Window boundaries never change a bit of any replica.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from flocklab.schemas import Scenario

from .checkpoint import BACKEND, PATH, STEP, CheckpointFn, CheckpointMismatch, State
from .checks import run_checks, time_to_converge
from .live import OBSERVATIONS_INTERVAL, ObservationFeed, ObservationsFn
from .replicas import Replicas
from .result import FrameSink, RunResult

WINDOW_AGENT_STEPS = 100_000  # the first window: a few ms to tens of ms of work
WINDOW_SECONDS: float | None = 0.1  # later windows' target length (None: keep the first)
PROGRESS_INTERVAL = 0.2  # seconds between progress callbacks

ProgressFn = Callable[[int, int], None]
StopFn = Callable[[], bool]


@dataclass
class Hooks:
    """What a caller hears of a running set of replicas, and how it stops them."""

    on_progress: ProgressFn | None = None
    should_stop: StopFn | None = None
    on_observations: ObservationsFn | None = None  # a single replica only
    observations_interval: float = OBSERVATIONS_INTERVAL
    on_checkpoint: CheckpointFn | None = None  # a single replica only


def run_replicas(make: Callable[[list[Scenario]], Replicas], scenarios: Sequence[Scenario],
                 *, path: str, backend: str, sinks: Sequence[FrameSink | None] | None = None,
                 hooks: Hooks | None = None, resume: State | None = None
                 ) -> list[RunResult]:
    """Run `scenarios` on the schedule `make` builds (named `path`) to the end, to
    cancellation or to blow-up; results in input order. `resume`: a single replica's
    checkpoint (`Replicas.save` plus its step), from which the run goes on; the frames up
    to that step are the sink's already."""
    sinks = list(sinks) if sinks is not None else [None] * len(scenarios)
    # From a queue, the largest replicas first: every window then ends on a small one
    # instead of leaving one core alone with a large one. A replica's bits do not depend
    # on its place in the set.
    order = list(range(len(scenarios)))
    if getattr(make, "QUEUED", False):
        order.sort(key=lambda b: -scenarios[b].n_agents)
    results = _Run(make, [scenarios[b] for b in order], [sinks[b] for b in order], path,
                   backend, hooks or Hooks(), resume).results()
    place = {b: j for j, b in enumerate(order)}
    return [results[place[b]] for b in range(len(scenarios))]


class _Run:
    """One driven set of replicas, in launch order."""

    def __init__(self, make: Callable[[list[Scenario]], Replicas], scenarios: list[Scenario],
                 sinks: list[FrameSink | None], path: str, backend: str, hooks: Hooks,
                 resume: State | None = None):
        self.t0 = time.perf_counter()
        self.batch = make(scenarios)
        self.start = 0
        if resume is not None:
            for key, now in ((PATH, path), (BACKEND, backend)):
                if str(resume[key]) != now:
                    raise CheckpointMismatch(f"the checkpoint ran on {key.split('/')[1]} "
                                             f"{str(resume[key])!r}, this run on {now!r}")
            try:
                self.batch.load(resume)
            except KeyError as exc:  # another model's or schedule's arrays
                raise CheckpointMismatch(f"the checkpoint has no array {exc} of this "
                                         f"{scenarios[0].model.kind} run") from None
            self.start = int(resume[STEP])
        self.setup = time.perf_counter() - self.t0
        self.scenarios, self.sinks, self.path, self.backend = scenarios, sinks, path, backend
        self.hooks = hooks
        self.steps = [s.time.steps for s in scenarios]
        self.frame_every = [s.recording.every if s.recording.enabled and sinks[b] is not None
                            else 0 for b, s in enumerate(scenarios)]
        self.arrays = [[a for a in s.recording.arrays if a in type(s.model).state_arrays]
                       for s in scenarios]
        self.recorded = [bool(a or s.recording.derived)
                         for a, s in zip(self.arrays, scenarios, strict=True)]
        self.cancelled = False
        self.s = 0
        rec = scenarios[0].recording
        on = hooks.on_checkpoint is not None and len(scenarios) == 1
        self.ckpt_every = rec.checkpoint_every if on else 0
        self.ckpt_seconds = rec.checkpoint_seconds if on else None
        if self.ckpt_every or self.ckpt_seconds is not None:
            self.batch.save()  # a schedule without checkpoints refuses here, not midway

    def record(self, step: int, last: bool = False) -> None:
        """Frames due at `step` (every k steps and at each replica's end; `last`: the
        stopping step of a cancelled run, unless its frame is already there)."""
        if not any(self.frame_every):
            return
        status = self.batch.status()
        for b, sink in enumerate(self.sinks):
            k = self.frame_every[b]
            if not k or not self.recorded[b] or step > self.steps[b]:
                continue
            due = step == self.steps[b] or (step % k != 0 if last else step % k == 0)
            if due and self.batch.divergence(b, status) is None:
                sink.frame(step, step * self.scenarios[b].time.dt,
                           self.batch.frame(b, self.arrays[b], step))

    def next_stop(self, s: int, window: int, last: int) -> int:
        """The end of the window from s: `window` steps on, or the next frame to record."""
        nxt = min(s + window, last + 1)
        for b, k in enumerate(self.frame_every):
            if k and s < self.steps[b]:
                nxt = min(nxt, (s // k + 1) * k, self.steps[b])
        if self.ckpt_every:
            nxt = min(nxt, (s // self.ckpt_every + 1) * self.ckpt_every)
        return nxt

    def checkpoint(self, s: int, now: float, last: float) -> float:
        """Hand the state at s (a window's end) to `on_checkpoint` when due: at every
        k-th step, or `checkpoint_seconds` after the last one. Returns when the last one
        was taken. A diverged replica is not checkpointed (its end is already known)."""
        due = (self.ckpt_every and s % self.ckpt_every == 0) or (
            self.ckpt_seconds is not None and now - last >= self.ckpt_seconds)
        if not due or s == self.start or self.batch.divergence(0, self.batch.status()):
            return last
        assert self.hooks.on_checkpoint is not None
        self.hooks.on_checkpoint(s, {**self.batch.save(), STEP: np.array(s, np.int64),
                                     PATH: np.array(self.path), BACKEND: np.array(self.backend)})
        return time.perf_counter()

    def drive(self) -> None:
        """Windows to the last replica's end (or to cancellation)."""
        batch, hooks = self.batch, self.hooks
        last = max(self.steps)
        agents = sum(s.n_agents for s in self.scenarios)
        window = getattr(batch, "FIRST_WINDOW", None) or max(1, WINDOW_AGENT_STEPS // agents)
        # The schedule's series are already the result's columns: nothing to filter.
        feed = (ObservationFeed(hooks.on_observations, None, hooks.observations_interval)
                if hooks.on_observations is not None and len(self.scenarios) == 1 else None)
        if self.start == 0:
            self.record(0)
        s, last_progress = self.start, time.perf_counter()
        last_ckpt = last_progress
        while s <= last:
            nxt = self.next_stop(s, window, last)
            started = time.perf_counter()
            batch.advance(s, nxt)
            took = time.perf_counter() - started
            if WINDOW_SECONDS is not None and nxt - s >= window and took > 0:
                window = max(1, min(8 * window, int(window * WINDOW_SECONDS / took)))
            s = nxt
            self.record(s)
            if s > last:
                break
            now = time.perf_counter()
            if self.ckpt_every or self.ckpt_seconds is not None:
                last_ckpt = self.checkpoint(s, now, last_ckpt)
            if hooks.on_progress is not None and now - last_progress >= PROGRESS_INTERVAL:
                last_progress = now
                hooks.on_progress(min(s, last), last)
            if feed is not None and feed.due(now):
                feed.send(_series(batch, 0, batch.status(), self.scenarios[0]), now)
            if hooks.should_stop is not None and hooks.should_stop():
                self.cancelled = True
                batch.end_at(s)
                batch.advance(s, s + 1)  # the final observation at the stopping step
                self.record(s, last=True)
                break
        self.s = s

    def results(self) -> list[RunResult]:
        self.drive()
        status = self.batch.status()
        wall = time.perf_counter() - self.t0
        out = [self.result(b, status, wall) for b in range(len(self.scenarios))]
        if self.hooks.on_progress is not None and len(self.scenarios) == 1:
            self.hooks.on_progress(out[0].steps, self.steps[0])
        return out

    def result(self, b: int, status: np.ndarray, wall: float) -> RunResult:
        """Replica b's result from the schedule's counters after the last window."""
        sc = self.scenarios[b]
        obs = _series(self.batch, b, status, sc)
        div = self.batch.divergence(b, status)
        done = min(self.s, self.steps[b]) if div is None else div[0]
        error = None
        if div is not None:
            step, quantity, cause = div
            error = {"step": step, "time": step * sc.time.dt, "quantity": quantity,
                     "cause": cause,
                     "message": f"step {step}: non-finite or runaway {quantity}; "
                                f"likely cause: {cause}"}
        state = "diverged" if div is not None else "cancelled" if self.cancelled and (
            done < self.steps[b]) else "completed"
        tol = sc.convergence.tolerance
        return RunResult(
            status=state, backend=self.backend, steps=done, wall_seconds=wall,
            n_agents=sc.n_agents, observables=obs,
            final={k: float(v[-1]) for k, v in obs.items() if len(v)},
            convergence={k: time_to_converge(obs["time"], obs[k], tol)
                         for k in self.batch.convergence_keys() if k in obs},
            extra={"setup_seconds": self.setup, "engine_path": self.path,
                   **self.batch.extra(b, status), **run_checks(sc, obs)},
            error=error,
        )


def _series(batch: Replicas, b: int, status: np.ndarray, sc: Scenario
            ) -> dict[str, np.ndarray]:
    """Replica b's observables so far: float64 whatever the kernels' precision, with
    `time` after `step`."""
    obs = {k: np.asarray(v, dtype=np.float64) for k, v in batch.observables(b, status).items()}
    return {"step": obs["step"], "time": obs["step"] * sc.time.dt,
            **{k: v for k, v in obs.items() if k != "step"}}
