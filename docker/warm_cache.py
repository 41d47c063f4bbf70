"""Fill Taichi's offline compile cache with every model family's kernels (image build step).

Runs each preset, each scenario in the examples folder and the first run of each sweep
(examples and named sweeps) for a few steps, on its own engine path (fused for small N,
per-step above `FUSED_MAX_N`) and once more on the per-step path, so that the first job
of any model in a fresh container loads its kernels from the cache instead of compiling.

Taichi keys cached kernels by the CPU thread count too (a run with 1 thread does not hit
kernels compiled for 2), so the pass is repeated for each count in `--threads` (default:
the cores this build may use, which is what a run on the same machine uses).

    python docker/warm_cache.py EXAMPLES_DIR [--threads 1 2 4]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Literal, get_args, get_origin

import numpy as np
from pydantic import ValidationError

from flocklab.kernels import engine, runtime
from flocklab.schemas import PRESETS, Scenario, get_preset
from flocklab.schemas.catalog import MODELS
from flocklab.schemas.sweep import is_sweep_document, load_sweep
from flocklab.schemas.sweep_presets import SWEEP_PRESETS, get_sweep_preset

WARM_STEPS = 3
# Vicsek-family rules no preset uses (their kernels differ by rule): model fields merged
# into the vicsek-1995 preset.
RULE_VARIANTS = [{"rule": "average"}, {"rule": "laplacian", "g": 301.0}]


def scenarios(examples: Path) -> list[tuple[str, Scenario]]:
    """Every preset, the rule variants, each example scenario, the first run of each sweep
    and the option variants, by name."""
    out = [(f"preset:{name}", get_preset(name)) for name in sorted(PRESETS)]
    base = get_preset("vicsek-1995").model_dump(mode="json")
    for fields in RULE_VARIANTS:
        doc = {**base, "model": {**base["model"], **fields}}
        out.append((f"vicsek-1995 rule={fields['rule']}", Scenario.model_validate(doc)))
    for path in sorted(examples.glob("*.json")):
        doc = json.loads(path.read_text())
        if is_sweep_document(doc):
            out.append((f"{path.name}[0]", load_sweep(doc).expand()[0].scenario))
        else:
            out.append((path.name, Scenario.model_validate(doc)))
    out += [(f"sweep:{name}[0]", get_sweep_preset(name).expand()[0].scenario)
            for name in sorted(SWEEP_PRESETS)]
    return out + option_variants(out) + lean_variants(out)


def lean_variants(found: list[tuple[str, Scenario]]) -> list[tuple[str, Scenario]]:
    """The Vicsek family's fused kernel comes in two builds: with the graph's components,
    Theorem 2's intervals and the heading spread, and without (a run recording none of
    them, as most sweeps do). For each rule and geometry in `found`, the build it lacks."""
    vicsek = [(name, sc) for name, sc in found if sc.model.kind == "vicsek"]
    key = engine.kernel_for("vicsek").fused.batch_key
    seen = {key(sc) for _, sc in vicsek}
    out = []
    for name, sc in vicsek:
        doc = sc.model_dump(mode="json")
        doc["model"]["track_linked_intervals"] = False
        doc["recording"]["observables"] = ["polarization"]
        lean = Scenario.model_validate(doc)
        if key(lean) not in seen:
            seen.add(key(lean))
            out.append((f"{name} observables=polarization", lean))
    return out


def option_variants(found: list[tuple[str, Scenario]]) -> list[tuple[str, Scenario]]:
    """For each model's option (a field with a fixed set of values: integrator, neighbour
    search, ...) every value no scenario in `found` uses, set on that model's first
    scenario that accepts it; kernels differ by these."""
    out = []
    for kind, cls in MODELS.items():
        bases = [sc for _, sc in found if sc.model.kind == kind]
        for name, field in cls.model_fields.items():
            if name == "kind" or get_origin(field.annotation) is not Literal or not bases:
                continue
            used = {getattr(sc.model, name) for sc in bases}
            for value in get_args(field.annotation):
                if value not in used:
                    out += _variant(bases, kind, name, value)
    return out


def _variant(bases: list[Scenario], kind: str, name: str,
             value: str) -> list[tuple[str, Scenario]]:
    """`value` for option `name` on the first of `bases` the schema accepts it on."""
    reason = ""
    for sc in bases:
        doc = sc.model_dump(mode="json")
        doc["model"][name] = value
        try:
            return [(f"{kind} {name}={value}", Scenario.model_validate(doc))]
        except ValidationError as exc:
            reason = exc.errors()[0]["msg"]
    print(f"warm: skipped {kind} {name}={value}: {reason}", flush=True)
    return []


def shortened(sc: Scenario, threads: int) -> Scenario:
    """The same scenario (same kernels) for a few steps, on `threads` CPU threads. The
    recording stays as it is: steps that observe and steps that do not run different
    kernels, and both occur (observables at step 0 and at the end, none between)."""
    doc = sc.model_dump(mode="json")
    doc["time"]["steps"] = WARM_STEPS
    doc["threads"] = threads
    return Scenario.model_validate(doc)


class Discard:
    """A frame sink that drops the frames: with a sink the engine records frames as a real
    run does, through kernels (and step windows) a run without one never uses."""

    def frame(self, step: int, time: float, arrays: dict[str, np.ndarray]) -> None:
        del step, time, arrays


def warm(name: str, sc: Scenario) -> None:
    """Compile `sc`'s kernels on its own path and on the per-step path."""
    t0 = time.perf_counter()
    paths = [engine.run(sc, sink=Discard()).extra.get("engine_path", "?")]
    if paths[0] != "per_step":
        # The per-step schedule runs these models above FUSED_MAX_N (or off the CPU).
        paths.append(engine.run(sc, sink=Discard(), path="per_step").extra["engine_path"])
    print(f"warm: {name} N={sc.n_agents} threads={sc.threads} paths={'+'.join(paths)} "
          f"{time.perf_counter() - t0:.1f}s", flush=True)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("examples", type=Path, help="folder of example scenarios and sweeps")
    p.add_argument("--threads", type=int, nargs="*", default=None,
                   help="CPU thread counts to warm for (default: this machine's cores)")
    args = p.parse_args(argv)
    counts = args.threads or [runtime.default_threads()]
    todo = scenarios(args.examples)
    t0 = time.perf_counter()
    for threads in counts:
        for name, sc in todo:
            warm(name, shortened(sc, threads))
    # The offline cache is written when Taichi resets (or exits cleanly).
    import taichi as ti
    ti.reset()
    print(f"warm: {len(todo)} scenarios x threads {counts} in "
          f"{time.perf_counter() - t0:.0f}s", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
