"""A checked sweep's runs in O(1) memory per run, and its pending runs as a lazy feed.

A 10^5-run sweep expanded at once (`Sweep.expand`: a validated Scenario per run) took a
service worker to several hundred MiB before its first run. The runner instead checks
every run in one pass of `Sweep.iter_runs` and keeps, of each, only what the tables and
sweep.json print without its scenario (`RunIndex`: point, replica, seed; per grid point
N and whether it checkpoints); the runs themselves are made again, a point at a time,
as the executor asks for them (`PendingRuns`), and a grid point's axis values come
again from `Sweep.grid_values`.
"""

from __future__ import annotations

from array import array
from collections.abc import Callable, Iterator
from dataclasses import dataclass

from flocklab.schemas.sweep import Sweep, SweepRun


@dataclass(frozen=True)
class PointRuns:
    """One grid point's runs as the tables list them: the point, its axis values, N,
    and (index, replica, seed) of each of its runs."""

    point: int
    values: dict
    n_agents: int
    runs: list[tuple[int, int, int]]


class RunIndex:
    """Point, replica and seed of every run of a sweep (arrays of int64), and per grid
    point its N and whether its runs checkpoint: built by `build`, which checks every
    run (SweepError as `Sweep.expand` raises it) and keeps none."""

    def __init__(self, sweep: Sweep):
        self.sweep = sweep
        self.point = array("q")
        self.replica = array("q")
        self.seed = array("q")
        self.first = array("q")  # per point: the index of its first run
        self.n_agents = array("q")  # per point
        self.checkpoints = bytearray()  # per point: 1 when its runs checkpoint
        self.total_agent_steps = 0

    @classmethod
    def build(cls, sweep: Sweep) -> RunIndex:
        index = cls(sweep)
        for run in sweep.iter_runs():
            if run.point == len(index.first):  # runs come point by point, in order
                index.first.append(run.index)
                index.n_agents.append(run.scenario.n_agents)
                # (run_checkpoints.wants_checkpoints, without importing the executors)
                index.checkpoints.append(run.scenario.recording.checkpoints)
            index.point.append(run.point)
            index.replica.append(run.replica)
            index.seed.append(run.seed)
            index.total_agent_steps += run.scenario.n_agents * run.scenario.time.steps
        return index

    @property
    def n_runs(self) -> int:
        return len(self.point)

    @property
    def n_points(self) -> int:
        return len(self.first)

    def wants_checkpoints(self, index: int) -> bool:
        return bool(self.checkpoints[self.point[index]])

    def points(self) -> Iterator[PointRuns]:
        """Every grid point with its runs, in order, one at a time."""
        bounds = [*self.first, self.n_runs]
        for p, values in enumerate(self.sweep.grid_values()):
            runs = [(i, self.replica[i], self.seed[i]) for i in range(bounds[p], bounds[p + 1])]
            yield PointRuns(p, values, self.n_agents[p], runs)


class PendingRuns:
    """The runs of `sweep` for which `pending(index)` holds, made as they are iterated
    (a grid point at a time, none kept: `Sweep.iter_runs`); `len` is fixed at the start.
    Iterable more than once (each pass makes them again)."""

    def __init__(self, sweep: Sweep, pending: Callable[[int], bool], count: int):
        self.sweep, self.pending, self.count = sweep, pending, count

    def __len__(self) -> int:
        return self.count

    def __iter__(self) -> Iterator[SweepRun]:
        if self.count:
            yield from self.sweep.iter_runs(self.pending)
