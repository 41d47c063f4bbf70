"""Bit-identity guard for engine refactors: hash every example and preset's final state.

Runs every scenario in `examples/*.json` (sweeps are skipped) and every registered preset,
plus an RK4 twin of each that integrates with Euler (none of them uses RK4 itself), on
each schedule that applies to it (per-step always; fused where "auto" takes it; batched
wherever it covers the scenario: `kernels.run(..., path=...)`), and writes one JSON object
per case: sha256 of the final per-agent arrays (position, velocity, heading: those the
model has) and of every observable series. Runs are cut to `--steps` steps (default 1000),
and those of more than `--large-n` agents to `--large-steps` (default 150), which keeps the
whole check to a few minutes on two cores. A pure move of code must leave every hash
unchanged:

    python bench/bits_check.py --out base.json                  # on the old code
    python bench/bits_check.py --out new.json --compare base.json   # on the new code

With `--compare FILE` every case whose hashes differ (or that is missing on either side) is
listed and the exit status is 1. Only the public engine API is used, so the same script
runs on the code before and after a restructuring.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
ARRAYS = ["position", "velocity", "heading"]


class LastFrame:
    """A frame sink that keeps only the latest frame."""

    def __init__(self) -> None:
        self.arrays: dict[str, np.ndarray] = {}

    def frame(self, step: int, time: float, arrays: dict[str, np.ndarray]) -> None:
        self.arrays = {k: np.array(v) for k, v in arrays.items()}


def digest(a: np.ndarray) -> str:
    """sha256 of an array's dtype, shape and bytes (C order)."""
    a = np.ascontiguousarray(a)
    h = hashlib.sha256(f"{a.dtype.str}{a.shape}".encode())
    h.update(a.tobytes())
    return h.hexdigest()


def scenarios(max_steps: int, large_n: int, large_steps: int
              ) -> Iterator[tuple[str, dict[str, Any]]]:
    """(case name, scenario document) for every example scenario and preset, with the step
    count cut to `max_steps` (`large_steps` above `large_n` agents), and the final frame of
    every per-agent array recorded."""
    from pydantic import ValidationError

    from flocklab.schemas import PRESETS, Scenario, get_preset

    docs: list[tuple[str, dict[str, Any]]] = []
    for path in sorted((ROOT / "examples").glob("*.json")):
        doc = json.loads(path.read_text())
        if "base" in doc and "axes" in doc:  # a sweep, not a scenario
            continue
        docs.append((f"example:{path.stem}", Scenario.model_validate(doc).model_dump(mode="json")))
    for name in sorted(PRESETS):
        docs.append((f"preset:{name}", get_preset(name).model_dump(mode="json")))
    for name, doc in list(docs):  # an RK4 twin, where the model integrates with RK4 too
        twin = {**doc, "model": {**doc["model"], "integrator": "rk4"}}
        if doc["model"].get("integrator") in ("euler", "semi_implicit_euler"):
            try:
                Scenario.model_validate(twin)
            except ValidationError:  # Olfati-Saber: semi-implicit Euler only
                continue
            docs.append((f"{name}+rk4", twin))
    for name, doc in docs:
        large = Scenario.model_validate(doc).n_agents > large_n
        steps = min(doc["time"]["steps"], large_steps if large else max_steps)
        doc["time"] = {**doc["time"], "steps": steps}
        doc["recording"] = {**doc.get("recording", {}), "every": steps, "arrays": ARRAYS,
                            "observables_every": 1}
        doc["backend"] = "cpu"
        yield name, doc


def run_case(doc: dict[str, Any], path: str) -> dict[str, Any]:
    """Run one scenario on `path` ("per_step" or "fused") and hash what it produced."""
    from flocklab import kernels
    from flocklab.schemas import Scenario

    scenario = Scenario.model_validate(doc)
    sink = LastFrame()
    res = kernels.run(scenario, sink=sink, path=path)
    return {
        "status": res.status,
        "steps": res.steps,
        "engine_path": res.extra.get("engine_path"),
        "arrays": {k: digest(v) for k, v in sorted(sink.arrays.items())},
        "observables": {k: digest(v) for k, v in sorted(res.observables.items())},
    }


def paths_for(doc: dict[str, Any]) -> list[str]:
    """The schedules that apply to a scenario: per-step always, fused where "auto" takes
    it, batched wherever it covers the scenario."""
    from flocklab.kernels import engine
    from flocklab.schemas import Scenario

    sc = Scenario.model_validate(doc)
    out = ["per_step"]
    if engine.choose_path(sc, "cpu") == "fused":
        out.append("fused")
    try:
        engine.schedule(sc, "cpu", "batched")
        out.append("batched")
    except engine.PathUnavailable:
        pass
    return out


def compare(now: dict[str, Any], base: dict[str, Any]) -> list[str]:
    """Every difference between two result files, one line each."""
    out = []
    for case in sorted(set(now) | set(base)):
        if case not in base:
            out.append(f"{case}: not in the baseline")
        elif case not in now:
            out.append(f"{case}: missing from this run")
        elif now[case] != base[case]:
            a, b = now[case], base[case]
            keys = [k for k in ("status", "steps", "engine_path") if a.get(k) != b.get(k)]
            for part in ("arrays", "observables"):
                names = set(a.get(part, {})) | set(b.get(part, {}))
                keys += [f"{part}.{n}" for n in sorted(names)
                         if a.get(part, {}).get(n) != b.get(part, {}).get(n)]
            out.append(f"{case}: differs in {', '.join(keys)}")
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", type=Path, default=Path("bits.json"), help="result JSON to write")
    ap.add_argument("--compare", type=Path, help="baseline JSON: exit 1 on any mismatch")
    ap.add_argument("--steps", type=int, default=1000, help="step cap (default 1000)")
    ap.add_argument("--large-n", type=int, default=1000,
                    help="scenarios of more agents are cut to --large-steps (default 1000)")
    ap.add_argument("--large-steps", type=int, default=150,
                    help="step cap of the large scenarios (default 150)")
    args = ap.parse_args(argv)

    from flocklab.kernels import runtime

    runtime.ensure("cpu")
    results: dict[str, Any] = {}
    t0 = time.perf_counter()
    for name, doc in scenarios(args.steps, args.large_n, args.large_steps):
        for path in paths_for(doc):
            t = time.perf_counter()
            results[f"{name}[{path}]"] = run_case(doc, path)
            print(f"{name}[{path}]: {time.perf_counter() - t:.1f} s", file=sys.stderr)
    args.out.write_text(json.dumps(results, indent=1, sort_keys=True) + "\n")
    print(f"{len(results)} cases in {time.perf_counter() - t0:.0f} s -> {args.out}")
    if args.compare is None:
        return 0
    diffs = compare(results, json.loads(args.compare.read_text()))
    for line in diffs:
        print(line)
    print(f"{len(results) - len(diffs)} identical, {len(diffs)} mismatched")
    return 1 if diffs else 0


if __name__ == "__main__":
    sys.exit(main())
