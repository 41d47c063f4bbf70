"""`python -m flocklab.service.render.worker`: draw one picture or movie in a child process.

The service runs this per render request (then caches the file), so the API process never
imports matplotlib, h5py's big reads or the engine's helpers, and a slow 10^6-agent draw
never holds the API's GIL. Protocol: one JSON request on stdin
  {"what": "snapshot" | "observables" | "movie" | "sweep", "folder": ..., "out": ...,
   "options": {...}}
and one JSON line on stdout: what was drawn (exit 0), or
  {"detail": ..., "loc": ..., "status": ...} for bad input (exit 2) or a missing
  plotting library (exit 3).
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path
from typing import Any

from .errors import PlottingUnavailable, RenderInputError

EXIT_OK, EXIT_BAD_INPUT, EXIT_UNAVAILABLE = 0, 2, 3


def render_request(req: dict[str, Any]) -> dict[str, Any]:
    """Draw what `req` asks into req["out"]; returns a summary of what was drawn."""
    from .figure import new_figure, save
    from .run_data import RunData, load_sweep
    from .snapshot import SnapshotOptions, draw_snapshot

    what, folder, out = req["what"], Path(req["folder"]), Path(req["out"])
    o = req.get("options", {})
    w, h = int(o.get("width", 800)), int(o.get("height", 800))
    if what == "sweep":
        from .plots import draw_sweep

        fig = new_figure(w, h)
        drawn = draw_sweep(fig, load_sweep(folder), o.get("names"), w, h)
        save(fig, out)
        return {"measures": drawn}
    run = RunData(folder)
    if what == "observables":
        from .plots import draw_observables

        fig = new_figure(w, h)
        drawn = draw_observables(fig, run, o.get("names"), w, h)
        save(fig, out)
        return {"observables": drawn}
    opts = SnapshotOptions(w, h, o.get("field", "auto"), o.get("edges"), o.get("trails"),
                           o.get("overlays", True))
    if what == "movie":
        from .movie import write_movie

        n = write_movie(run, out, opts, fps=float(o.get("fps", 20.0)),
                        stride=int(o.get("stride", 1)))
        return {"frames": n}
    if what != "snapshot":
        raise RenderInputError(f"unknown render kind {what!r}")
    k = run.pick_frame(o.get("frame"), o.get("time"))
    fig = new_figure(w, h)
    info = draw_snapshot(fig, run, k, opts)
    save(fig, out)
    return {"frame": info.frame, "step": info.step, "time": info.time, "mode": info.mode,
            "agents": info.agents_drawn, "edges": info.edges_drawn}


def main() -> int:
    os.environ.setdefault("MPLBACKEND", "Agg")
    req = json.loads(sys.stdin.read())
    try:
        result = render_request(req)
    except RenderInputError as exc:
        print(json.dumps({"detail": str(exc), "loc": exc.loc, "status": exc.status}))
        return EXIT_BAD_INPUT
    except PlottingUnavailable as exc:
        print(json.dumps({"detail": str(exc), "loc": None, "status": 503}))
        return EXIT_UNAVAILABLE
    print(json.dumps(result))
    return EXIT_OK


if __name__ == "__main__":
    sys.exit(main())
