"""The commands' progress bar (`flocklab run`, `flocklab sweep`, `flocklab render`)."""

from __future__ import annotations

import sys
import time


class ProgressBar:
    """A one-line progress bar on a terminal; silent when stderr is not a terminal."""

    def __init__(self, enabled: bool, unit: str = "step"):
        self.enabled = enabled
        self.unit = unit
        self.t0 = time.perf_counter()

    def __call__(self, done: int, total: int) -> None:
        if not self.enabled:
            return
        frac = done / total if total else 1.0
        elapsed = time.perf_counter() - self.t0
        eta = elapsed * (1 - frac) / frac if frac > 0 else 0.0
        bar = "#" * int(30 * frac)
        sys.stderr.write(f"\r[{bar:<30}] {100 * frac:5.1f}%  {self.unit} {done}/{total}  "
                         f"eta {eta:6.1f}s")
        if done >= total:
            sys.stderr.write("\n")
        sys.stderr.flush()
