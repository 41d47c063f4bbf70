"""Rendering times against the issue's bar, one JSON line each:

  a 10^6-agent frame (a density field)          bar: < 5 s
  a 10^3-agent frame with its interaction edges bar: < 1 s
  a 200-frame MP4 of 10^4 agents                bar: < 60 s

Each case first runs a small Vicsek scenario into a temporary folder (not timed), then
times `flocklab render` twice: the whole command in a fresh process (`cli_seconds`,
including Python, matplotlib and h5py start-up) and the drawing and writing alone inside
this process (`render_seconds`).

    python bench/render_bench.py [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from flocklab.schemas import Scenario


def vicsek(n: int, steps: int, every: int) -> Scenario:
    return Scenario.model_validate({
        "name": f"bench-{n}", "model": {"kind": "vicsek", "rule": "vicsek", "v0": 0.03,
                                        "eta": 0.5},
        "space": {"kind": "periodic", "L": math.sqrt(n / 4)}, "neighbours": {"radius": 1.0},
        "initial": {"kind": "random", "N": n}, "time": {"steps": steps, "dt": 1.0},
        "recording": {"every": every, "arrays": ["position", "heading"],
                      "observables_every": max(1, every)}, "seed": 1})


CASES = [
    # name, scenario, render arguments, bar (s)
    ("frame_1e6_field", vicsek(1_000_000, 1, 1), ["--size", "800x800"], 5.0),
    ("frame_1e3_edges", vicsek(1000, 10, 10), ["--edges", "--size", "800x800"], 1.0),
    ("movie_200_frames_1e4", vicsek(10_000, 199, 1),
     ["--movie", "--size", "640x640", "--quiet"], 60.0),
]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--keep", type=Path, help="keep the runs and pictures in this folder")
    args = p.parse_args()
    from flocklab.service.execute import execute_to_dir
    from flocklab.service.render.cli import add_arguments, render

    root = args.keep or Path(tempfile.mkdtemp(prefix="render-bench-"))
    root.mkdir(parents=True, exist_ok=True)
    for name, sc, extra, bar in CASES:
        folder = root / name
        if not folder.exists():
            execute_to_dir(sc, folder)
        out = root / (f"{name}.mp4" if "--movie" in extra else f"{name}.png")
        argv = [str(folder), "--out", str(out), *extra]
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "flocklab", "render", *argv], check=True,
                       capture_output=True)
        cli = time.perf_counter() - t0
        parser = argparse.ArgumentParser()
        add_arguments(parser)
        t0 = time.perf_counter()
        drawn = render(parser.parse_args(argv))
        inner = time.perf_counter() - t0
        print(json.dumps({"case": name, "N": sc.n_agents, "cli_seconds": round(cli, 2),
                          "render_seconds": round(inner, 2), "bar_seconds": bar,
                          "within_bar": cli < bar, "drawn": drawn}), flush=True)


if __name__ == "__main__":
    main()
