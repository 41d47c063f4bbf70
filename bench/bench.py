"""flocklab benchmark: one JSON line per measurement.

    python -m bench.bench                      # every workload at N = 1e4, 1e5, 1e6
    python -m bench.bench --sizes 1000000 --models vicsek --no-baseline

Each measurement runs in its own process: a warm-up run compiles the kernels, the peak
resident memory is reset (/proc/self/clear_refs), then the timed run. `peak_bytes_per_agent`
is the growth of the peak RSS over the warmed-up process, divided by N (no frames are
recorded). `agent_steps_per_second` counts the stepping loop, observables included, and
excludes setup (state allocation and upload), reported as `setup_seconds`.
For Vicsek, the same run also times the numpy + scipy cKDTree version a Python user would
write (`baseline`), and the ratio.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import json
import pkgutil
import subprocess
import sys
from pathlib import Path

import bench


def workloads() -> dict:
    found = {}
    for mod in pkgutil.iter_modules([str(Path(bench.__file__).parent)]):
        if mod.name.startswith("workload_"):
            for label, builder in importlib.import_module(f"bench.{mod.name}").WORKLOADS:
                found[label] = builder
    return found


def default_steps(n: int) -> int:
    return int(min(3000, max(30, 3e7 / n)))


def _peak_rss() -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) * 1024
    return 0


def measure_one(label: str, n: int, steps: int, backend: str) -> dict:
    """Runs in a child process: warm up, reset the peak RSS, run, report."""
    from flocklab import kernels
    from flocklab.schemas import Scenario

    spec = workloads()[label](n)
    spec["backend"] = backend
    warm = dict(spec, time=dict(spec["time"], steps=2))
    kernels.run(Scenario.model_validate(warm))
    with contextlib.suppress(OSError):  # not Linux: the peak then includes the warm-up
        Path("/proc/self/clear_refs").write_text("5")  # reset VmHWM to the current RSS
    base = _peak_rss()
    spec["time"] = dict(spec["time"], steps=steps)
    sc = Scenario.model_validate(spec)
    result = kernels.run(sc)
    peak = _peak_rss()
    loop = result.wall_seconds - result.extra.get("setup_seconds", 0.0)
    model, _, rule = label.partition("/")
    return {
        "model": model, "rule": rule or None, "N": n, "steps": result.steps,
        "backend": result.backend, "status": result.status,
        "seconds": round(loop, 4), "setup_seconds": round(result.extra.get("setup_seconds", 0), 4),
        "agent_steps_per_second": round(n * result.steps / loop),
        "peak_bytes_per_agent": round((peak - base) / n, 1),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[10_000, 100_000, 1_000_000])
    ap.add_argument("--models", nargs="+", help="workload labels or model prefixes")
    ap.add_argument("--steps", type=int, help="steps per run (default: ~3e7 agent-steps)")
    ap.add_argument("--backend", default="cpu")
    ap.add_argument("--no-baseline", action="store_true", help="skip the cKDTree baseline")
    ap.add_argument("--one", nargs=2, metavar=("LABEL", "N"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.one:
        n = int(args.one[1])
        print(json.dumps(measure_one(args.one[0], n, args.steps or default_steps(n),
                                     args.backend)))
        return 0
    labels = [lb for lb in workloads()
              if not args.models or any(lb.startswith(m) for m in args.models)]
    for label in labels:
        for n in args.sizes:
            steps = args.steps or default_steps(n)
            cmd = [sys.executable, "-m", "bench.bench", "--one", label, str(n),
                   "--steps", str(steps), "--backend", args.backend]
            out = subprocess.run(cmd, capture_output=True, text=True)
            if out.returncode != 0:
                print(json.dumps({"model": label, "N": n, "error": out.stderr[-2000:]}))
                continue
            line = json.loads(out.stdout.strip().splitlines()[-1])
            if label == "vicsek/vicsek" and not args.no_baseline:
                from bench.ckdtree_vicsek import run as ckdtree_run

                base_steps = max(3, min(steps, int(3e6 / n)))
                secs = ckdtree_run(n, base_steps)
                rate = n * base_steps / secs
                line["baseline"] = {"impl": "numpy+scipy.cKDTree", "steps": base_steps,
                                    "agent_steps_per_second": round(rate)}
                line["speedup_vs_baseline"] = round(line["agent_steps_per_second"] / rate, 2)
            print(json.dumps(line), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
