"""`flocklab render`: a run folder's snapshot, observables or movie; a sweep's plot."""

from __future__ import annotations

import argparse
import gc
import json
import re
import sys
from pathlib import Path

from .errors import PlottingUnavailable, RenderInputError

EXIT_OK, EXIT_BAD_INPUT = 0, 2


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("folder", type=Path, help="a run folder (flocklab run --out) or a sweep "
                   "folder (table.csv + sweep.json)")
    p.add_argument("--out", type=Path, required=True,
                   help="picture (.png, .svg, .pdf) or movie (.mp4, .gif) to write")
    p.add_argument("--frame", type=int, help="frame index (negative: from the end; "
                   "default the last)")
    p.add_argument("--time", type=float, help="the last frame at or before this time")
    p.add_argument("--trails", type=int, nargs="?", const=0, metavar="FRAMES",
                   help="draw each agent's path over the last FRAMES frames (all if omitted)")
    p.add_argument("--field", choices=["auto", "arrows", "density", "polarization"],
                   default="auto", help="arrows per agent, or a field (auto: a density "
                   "field above 5000 agents)")
    p.add_argument("--edges", action=argparse.BooleanOptionalAction, default=None,
                   help="draw the interaction edges (default: at N <= 200)")
    p.add_argument("--no-overlays", action="store_true",
                   help="leave out obstacles, destination, leaders and offsets")
    p.add_argument("--plot", metavar="NAMES", nargs="?", const="",
                   help="plot observables against time (comma-separated; empty: the "
                   "model's usual ones); for a sweep, the measures to plot")
    p.add_argument("--movie", action="store_true", help="animate the recorded frames "
                   "(with --out .mp4 or .gif)")
    p.add_argument("--fps", type=float, default=20.0, help="movie frames per second")
    p.add_argument("--stride", type=int, default=1, help="movie: every k-th frame")
    p.add_argument("--size", default=None, metavar="WxH",
                   help="picture size in pixels (default 800x800, plots 900x700)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def main(argv: list[str] | None = None) -> int:
    """`flocklab render ARGS` without `service.cli` (see `service.entry`)."""
    p = argparse.ArgumentParser(prog="flocklab render",
                                description="draw a run (snapshot, observables, movie) "
                                "or a sweep")
    add_arguments(p)
    args = p.parse_args(argv)
    collecting = gc.isenabled()
    if not args.movie:
        # One picture, then the process ends: the cyclic collector would only walk the
        # objects of the imports and of the figure, none of them garbage (0.05-0.09 s of
        # the 0.8 s of CPU of a 10^3-agent snapshot). A movie keeps it, frame after frame.
        gc.disable()
    try:
        return cmd_render(args)
    except KeyboardInterrupt:
        print("flocklab render: interrupted", file=sys.stderr)
        return 1
    finally:
        if collecting:
            gc.enable()


def cmd_render(args: argparse.Namespace) -> int:
    try:
        summary = render(args)
    except (RenderInputError, PlottingUnavailable) as exc:
        print(f"flocklab render: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except ModuleNotFoundError as exc:  # h5py, scipy, or one of matplotlib's own
        print(f"flocklab render: {exc.name} is not installed: pip install 'flocklab[plot]'",
              file=sys.stderr)
        return EXIT_BAD_INPUT
    print(json.dumps({"out": str(args.out), **summary}))
    return EXIT_OK


def _size(text: str | None, default: tuple[int, int]) -> tuple[int, int]:
    if text is None:
        return default
    m = re.fullmatch(r"(\d{1,5})[xX](\d{1,5})", text)
    if not m:
        raise RenderInputError(f"--size {text!r}: write WIDTHxHEIGHT, e.g. 800x600")
    return int(m[1]), int(m[2])


def render(args: argparse.Namespace) -> dict[str, object]:
    """Do what the arguments ask; returns a JSON-able summary of what was drawn."""
    from .figure import image_format, new_figure, save
    from .run_data import RunData, is_sweep_dir, load_sweep
    from .snapshot import SnapshotOptions, draw_snapshot

    folder: Path = args.folder
    if not folder.is_dir():
        raise RenderInputError(f"{folder}: no such folder")
    out: Path = args.out
    if not out.parent.is_dir():
        raise RenderInputError(f"{out.parent}: no such folder for --out")
    names = [n.strip() for n in args.plot.split(",") if n.strip()] if args.plot else None
    if is_sweep_dir(folder):
        from .plots import draw_sweep

        w, h = _size(args.size, (900, 700))
        image_format(out)
        sweep = load_sweep(folder)
        fig = new_figure(w, h)
        drawn = draw_sweep(fig, sweep, names, w, h)
        save(fig, out)
        return {"kind": "sweep", "measures": drawn, "axes": sweep.axes}
    run = RunData(folder)
    if args.movie:
        from flocklab.service.progress import ProgressBar

        from .movie import write_movie

        w, h = _size(args.size, (800, 800))
        opts = SnapshotOptions(w, h, args.field, args.edges, args.trails,
                               not args.no_overlays)
        n = write_movie(run, out, opts, fps=args.fps, stride=args.stride,
                        on_progress=ProgressBar(sys.stderr.isatty() and not args.quiet,
                                                unit="frame"))
        return {"kind": "movie", "frames": n}
    if args.plot is not None:
        from .plots import draw_observables

        w, h = _size(args.size, (900, 700))
        image_format(out)
        fig = new_figure(w, h)
        drawn = draw_observables(fig, run, names, w, h)
        save(fig, out)
        return {"kind": "observables", "observables": drawn}
    w, h = _size(args.size, (800, 800))
    image_format(out)
    opts = SnapshotOptions(w, h, args.field, args.edges, args.trails, not args.no_overlays)
    k = run.pick_frame(args.frame, args.time)
    fig = new_figure(w, h)
    info = draw_snapshot(fig, run, k, opts)
    save(fig, out)
    return {"kind": "snapshot", "frame": info.frame, "step": info.step, "time": info.time,
            "mode": info.mode, "agents": info.agents_drawn, "edges": info.edges_drawn}


if __name__ == "__main__":
    sys.exit(main())
