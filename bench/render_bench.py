"""Rendering times against the issue's bar, one JSON line each:

  a 10^6-agent frame (a density field)          bar: < 5 s
  a 10^3-agent frame with its interaction edges bar: < 1 s
  a 200-frame MP4 of 10^4 agents                bar: < 60 s

and the same two frames of 3D runs (the cube at the same density; no bar of their own).

Each case first runs a small Vicsek scenario into a temporary folder (not timed), then
times `flocklab render` REPEAT times each way: the whole command in a fresh process, as
the `flocklab` console script runs it (`service.entry`; `cli_seconds` wall and
`cli_cpu_seconds` user + system, including Python, matplotlib and h5py start-up), and the
drawing and writing alone inside this process (`render_seconds`). `imports_cpu_seconds`
is the CPU time of a fresh interpreter that only imports what the command draws with
(numpy, h5py, and matplotlib as `service.render.figure` imports it). Medians are
printed, with the load average around the case: on a shared machine the wall time follows
the load, the CPU time much less.

    python bench/render_bench.py [--keep DIR] [--repeat R] [--only CASE]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from flocklab.schemas import Scenario


def vicsek(n: int, steps: int, every: int, dim: int = 2) -> Scenario:
    """Vicsek at density 4 in the periodic square (cube in 3D)."""
    return Scenario.model_validate({
        "name": f"bench-{n}", "model": {"kind": "vicsek", "rule": "vicsek", "v0": 0.03,
                                        "eta": 0.5},
        "space": {"kind": "periodic", "L": (n / 4) ** (1 / dim), "dimension": dim},
        "neighbours": {"radius": 1.0},
        "initial": {"kind": "random", "N": n}, "time": {"steps": steps, "dt": 1.0},
        "recording": {"every": every, "arrays": ["position", "heading"],
                      "observables_every": max(1, every)}, "seed": 1})


CASES = [
    # name, scenario, render arguments, bar (s)
    ("frame_1e6_field", vicsek(1_000_000, 1, 1), ["--size", "800x800"], 5.0),
    ("frame_1e3_edges", vicsek(1000, 10, 10), ["--edges", "--size", "800x800"], 1.0),
    ("movie_200_frames_1e4", vicsek(10_000, 199, 1),
     ["--movie", "--size", "640x640", "--quiet"], 60.0),
    ("frame_1e6_field_3d", vicsek(1_000_000, 1, 1, dim=3), ["--size", "800x800"], 5.0),
    ("frame_1e3_edges_3d", vicsek(1000, 10, 10, dim=3), ["--edges", "--size", "800x800"],
     1.0),
]


# What the render command imports before it draws, in a fresh interpreter.
IMPORTS = ("import numpy, h5py; from flocklab.service.render.figure import new_figure; "
           "new_figure(64, 64)")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--keep", type=Path, help="keep the runs and pictures in this folder")
    p.add_argument("--repeat", type=int, default=3, help="timings per case (medians)")
    p.add_argument("--only", choices=[c[0] for c in CASES], action="append",
                   help="run only this case (repeatable)")
    args = p.parse_args()
    from flocklab.service.execute import execute_to_dir
    from flocklab.service.render.cli import add_arguments, render

    root = args.keep or Path(tempfile.mkdtemp(prefix="render-bench-"))
    root.mkdir(parents=True, exist_ok=True)
    for name, sc, extra, bar in CASES:
        if args.only and name not in args.only:
            continue
        folder = root / name
        if not folder.exists():
            execute_to_dir(sc, folder)
        out = root / (f"{name}.mp4" if "--movie" in extra else f"{name}.png")
        argv = [str(folder), "--out", str(out), *extra]
        load_before = os.getloadavg()[0]
        walls, cpus, inners = [], [], []
        for _ in range(args.repeat):
            used = _children_cpu()
            t0 = time.perf_counter()
            subprocess.run([sys.executable, "-m", "flocklab.service.entry", "render", *argv],
                           check=True, capture_output=True)
            walls.append(time.perf_counter() - t0)
            cpus.append(_children_cpu() - used)
            parser = argparse.ArgumentParser()
            add_arguments(parser)
            t0 = time.perf_counter()
            drawn = render(parser.parse_args(argv))
            inners.append(time.perf_counter() - t0)
        imports = []
        for _ in range(args.repeat):
            used = _children_cpu()
            subprocess.run([sys.executable, "-c", IMPORTS], check=True, capture_output=True)
            imports.append(_children_cpu() - used)
        cli = statistics.median(walls)
        print(json.dumps({"case": name, "N": sc.n_agents, "repeat": args.repeat,
                          "cli_seconds": round(cli, 2),
                          "cli_cpu_seconds": round(statistics.median(cpus), 2),
                          "render_seconds": round(statistics.median(inners), 2),
                          "imports_cpu_seconds": round(statistics.median(imports), 2),
                          "cli_seconds_all": [round(t, 2) for t in walls],
                          "bar_seconds": bar, "within_bar": cli < bar,
                          "load_average": [round(load_before, 2), round(os.getloadavg()[0], 2)],
                          "drawn": drawn}), flush=True)


def _children_cpu() -> float:
    """User + system seconds of the finished child processes so far."""
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime


if __name__ == "__main__":
    main()
