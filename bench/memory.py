"""Peak memory of one run, counted the same way by bench/bench.py and bench/dimensions.py.

`peak_bytes_per_agent` is what a run at N needs beyond the process it starts in, divided
by N: a fresh process first runs the same workload at WARM_N agents (the per-step path,
so every kernel the big run launches is compiled or loaded from the offline cache), the
peak resident set is reset to the current one (/proc/self/clear_refs), the scenario runs
once, and the growth of the peak (VmHWM) is the run's: device arrays, the initial state
built on the host with its temporaries, the host copies made at observation steps, and
no recorded frames (the benchmarks record none).

Two ways of counting it gave different figures for the same run before (issue 13: Vicsek
160 B/agent in bench.bench, 282 in bench.dimensions):
- a warm-up at N itself leaves its freed host arrays in the C allocator's heap, resident;
  the measured run reuses them, so ~20 B/agent of the run's own host arrays went uncounted;
- a warm-up at N = 1000 takes the fused small-N path, so the per-step kernels were
  compiled inside the measured run (~80-100 MB of JIT memory, read as B/agent at 10^6),
  and a second run at N then peaked on top of the first's leftovers.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

# Above the engine's FUSED_MAX_N (10^4): the warm-up takes the per-step path the big run
# takes, and its own arrays (~20000 x 200 B) are a rounding error next to N = 10^6.
WARM_N = 20_000


def peak_rss() -> int:
    """The process's peak resident set (VmHWM) in bytes; 0 off Linux."""
    with contextlib.suppress(OSError):
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) * 1024
    return 0


def reset_peak() -> int:
    """Reset the peak resident set to the current one; returns it (bytes). Off Linux the
    peak keeps the warm-up's, and the growth reads low."""
    with contextlib.suppress(OSError):
        Path("/proc/self/clear_refs").write_text("5")
    return peak_rss()


def measured_run(scenario_at: Callable[[int, int], Any], n: int, steps: int,
                 warm_steps: int = 2) -> tuple[Any, float]:
    """Warm up at WARM_N, then run `scenario_at(n, steps)` (a validated Scenario) once:
    (its RunResult, peak bytes per agent). `scenario_at(size, steps)` builds the workload.
    At N <= the engine's FUSED_MAX_N the run takes the fused small-N path, whose kernels
    only a warm-up on that path compiles: it warms at N itself (its figure then misses the
    reused heap, a few MB, noise at that N anyway)."""
    from flocklab import kernels
    from flocklab.kernels.engine import FUSED_MAX_N

    kernels.run(scenario_at(WARM_N if n > FUSED_MAX_N else n, warm_steps))
    base = reset_peak()
    result = kernels.run(scenario_at(n, steps))
    return result, (peak_rss() - base) / n
