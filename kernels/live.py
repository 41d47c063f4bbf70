"""Handing a running run's observation rows to a callback as they are computed.

The engine evaluates observables every `recording.observables_every` steps and returns the
whole series at the end. A caller that wants to show them while the run goes on (the
service's worker, for the browser viewer) passes `on_observations` to `kernels.run`: it
gets the rows computed since its last call, batched so the stepping loop pays nothing
per observation (at most one hand-over every `OBSERVATIONS_INTERVAL` seconds, at the
points where progress is reported). The rows handed over during a run are, in order,
a prefix of the result's `observables` (same columns, same float64 values), and reading
them never changes a bit of the run: they are copies of what the run keeps anyway.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Collection, Mapping, Sequence

import numpy as np

ObservationsFn = Callable[[dict[str, np.ndarray]], None]
OBSERVATIONS_INTERVAL = 0.5  # seconds between hand-overs, at most


class ObservationFeed:
    """The rows of a growing series not yet handed to `callback`.

    `chosen` is the scenario's `recording.observables` (None: every name): the feed keeps
    the columns the result keeps, so the live rows have the final table's header.
    """

    def __init__(self, callback: ObservationsFn, chosen: Collection[str] | None,
                 interval: float = OBSERVATIONS_INTERVAL):
        self.callback = callback
        self.chosen = chosen
        self.interval = interval
        self.sent = 0
        self.last = time.perf_counter()

    def due(self, now: float) -> bool:
        """Whether a hand-over is due at `now` (a `time.perf_counter()` reading)."""
        return now - self.last >= self.interval

    def send(self, series: Mapping[str, Sequence[float] | np.ndarray], now: float) -> None:
        """Hand over the rows of `series` (every column as long as `series["step"]`)
        beyond those already sent; nothing when there are none."""
        self.last = now
        n = len(series["step"])
        if n <= self.sent:
            return
        rows = {k: np.asarray(v[self.sent:n], dtype=np.float64) for k, v in series.items()
                if self.chosen is None or k in ("step", "time") or k in self.chosen}
        self.sent = n
        self.callback(rows)
