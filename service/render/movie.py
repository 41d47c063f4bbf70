"""The recorded frames as a movie: MP4 (H.264 through the ffmpeg binary that the
`imageio-ffmpeg` wheel ships, no system install) or GIF (imageio)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from .errors import PlottingUnavailable, RenderInputError
from .figure import new_figure
from .limits import MAX_FPS, MIN_FPS
from .run_data import RunData
from .snapshot import Scene, SnapshotOptions, View, drawn_points, make_view

MOVIE_FORMATS = (".mp4", ".gif")


def write_movie(run: RunData, out: Path, opts: SnapshotOptions, *, fps: float = 20.0,
                start: int = 0, stop: int | None = None, stride: int = 1,
                on_progress: Callable[[int, int], None] | None = None) -> int:
    """Draw frames start:stop:stride into `out` (.mp4 or .gif); returns the frame count.

    The view is fixed over the movie (the box, or on the plane the extent of every
    frame), so the picture does not jump about.
    """
    suffix = Path(out).suffix.lower()
    if suffix not in MOVIE_FORMATS:
        raise RenderInputError(f"{out}: a movie is .mp4 or .gif")
    if not MIN_FPS <= fps <= MAX_FPS:
        raise RenderInputError(f"fps {fps:g} is outside {MIN_FPS:g}..{MAX_FPS:g}", loc="fps")
    if stride < 1:
        raise RenderInputError("stride must be >= 1", loc="stride")
    opts.check()
    # H.264 in yuv420p needs even sizes.
    opts.width, opts.height = opts.width - opts.width % 2, opts.height - opts.height % 2
    run.pick_frame(0)  # raises when there are no frames
    frames = range(start, run.n_frames if stop is None else min(stop, run.n_frames), stride)
    if len(frames) == 0:
        raise RenderInputError("no frames in the requested range", loc="stride")
    view = _movie_view(run, frames)
    try:
        import imageio.v2 as imageio
    except ImportError as exc:
        raise PlottingUnavailable("movies need imageio: pip install 'flocklab[plot]'") from exc

    scene = Scene(new_figure(opts.width, opts.height), run, opts, view)
    if suffix == ".mp4":
        # x264's "veryfast" preset: under half the encoder's CPU of its default "medium"
        # for a file of the same size at this quality (200 frames of 10^4 agents: 3.4 s
        # instead of 8.0 s, 6.0 MB against 5.9 MB)
        writer = imageio.get_writer(out, format="FFMPEG", fps=fps, codec="libx264",
                                    pixelformat="yuv420p", macro_block_size=2,
                                    ffmpeg_log_level="error", quality=7,
                                    output_params=["-preset", "veryfast"])
    else:
        writer = imageio.get_writer(out, format="GIF", duration=1000.0 / fps, loop=0)
    try:
        for i, k in enumerate(frames):
            scene.draw(k)
            rgba = scene.rgba()
            # ffmpeg is sent the canvas as it is (RGBA, written to its pipe at once); the
            # GIF writer keeps its frames, so it gets copies
            writer.append_data(rgba if suffix == ".mp4" else rgba[:, :, :3].copy())
            if on_progress is not None:
                on_progress(i + 1, len(frames))
    finally:
        writer.close()
    return len(frames)


def _movie_view(run: RunData, frames: range) -> View:
    if run.box is not None:
        return make_view(run, run.frame(frames[0]).position)
    import numpy as np

    from . import geometry

    lo, hi = np.full(run.dimension, np.inf), np.full(run.dimension, -np.inf)
    for k in frames:  # one frame at a time: never the whole trajectory in memory
        p = run.frame(k).position
        lo, hi = np.minimum(lo, p.min(axis=0)), np.maximum(hi, p.max(axis=0))
    points = drawn_points(np.array([lo, hi]), None, geometry.obstacles(run),
                          geometry.leaders(run, frames[-1]))
    return make_view(run, points)
