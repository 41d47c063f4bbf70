"""One frame drawn as the papers draw it.

Small N: each agent an arrow along its heading (Vicsek) or its velocity (the double
integrators and M4, length relative to the fastest agent of the frame), coloured by
heading; the interaction edges; obstacles and the destination (M3); the virtual leader,
its path and the formation offsets b_i to each agent's virtual leader r_id (M4); the
periodic box. Large N (above `FIELD_ABOVE` agents, where arrows are a blur): a density or
local-polarization field on a grid, with the mean heading as a coarse arrow field.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from . import geometry
from .errors import RenderInputError
from .figure import check_size
from .run_data import Frame, RunData

FIELD_ABOVE = 5000  # agents: arrows beyond this are unreadable at any picture size
EDGES_MAX_AGENTS = 200  # edges drawn by default up to here (the papers' N; denser is a blur)
FIELD_BINS = 160  # grid cells along the longer side of a field picture
COARSE_ARROWS = 20  # mean-heading arrows along the longer side over a field
Field = Literal["auto", "arrows", "density", "polarization"]
FIELDS: tuple[str, ...] = ("auto", "arrows", "density", "polarization")


@dataclass
class SnapshotOptions:
    """What to draw (shared by the CLI, the HTTP routes and movies)."""

    width: int = 800
    height: int = 800
    field: Field = "auto"
    edges: bool | None = None  # None: at N <= EDGES_MAX_AGENTS when the model has a graph
    trails: int | None = None  # frames of path behind each agent; 0 = from the first frame
    overlays: bool = True  # obstacles, destination, leaders, path, offsets

    def check(self) -> None:
        check_size(self.width, self.height)
        if self.field not in FIELDS:
            raise RenderInputError(f"field {self.field!r}: use one of {', '.join(FIELDS)}",
                                   loc="field")
        if self.trails is not None and self.trails < 0:
            raise RenderInputError("trails must be >= 0 frames (0: from the first frame)",
                                   loc="trails")


@dataclass
class SnapshotInfo:
    """What was drawn: tests and callers check counts against the run."""

    frame: int
    step: int
    time: float
    mode: str  # "arrows", "density" or "polarization"
    agents_drawn: int
    edges_drawn: int
    trails_drawn: int


def draw_snapshot(fig: Any, run: RunData, k: int, opts: SnapshotOptions,
                  view: tuple[float, float, float, float] | None = None) -> SnapshotInfo:
    """Draw frame k onto `fig` (cleared first). `view` fixes the limits."""
    return Scene(fig, run, opts, view).draw(k)


class Scene:
    """A figure drawn once and then moved frame to frame (a movie): the first `draw`
    builds the axes and artists, later ones only replace their data, which is several
    times cheaper than drawing the axes anew."""

    def __init__(self, fig: Any, run: RunData, opts: SnapshotOptions,
                 view: tuple[float, float, float, float] | None = None):
        opts.check()
        self.fig, self.run, self.opts, self.view = fig, run, opts, view
        self.mode = opts.field
        if self.mode == "auto":
            self.mode = "density" if run.n_agents > FIELD_ABOVE else "arrows"
        if self.mode != "arrows" and opts.trails is not None:
            raise RenderInputError(f"trails are drawn only with arrows (N <= {FIELD_ABOVE}, "
                                   "or field=arrows)", loc="trails")
        self.want_edges = self.mode == "arrows" and (opts.edges if opts.edges is not None else (
            run.n_agents <= EDGES_MAX_AGENTS and run.kind != "formation"))
        self.artists: dict[str, Any] = {}  # everything that changes from frame to frame
        self._background: Any = None

    def draw(self, k: int) -> SnapshotInfo:
        run, opts = self.run, self.opts
        fr = run.frame(k)
        obst = geometry.obstacles(run) if opts.overlays else None
        lead = geometry.leaders(run, fr.time) if opts.overlays else None
        trail_pos = _trails(run, k, opts.trails) if opts.trails is not None else None
        if self.view is None:
            self.view = view_limits(run, fr.position, trail_pos, obst, lead)
        first = not self.artists
        if first:
            self._build(obst)
        a = self.artists
        edges_drawn = trails_drawn = 0
        if self.mode == "arrows":
            if trail_pos is not None:
                trails_drawn = len(_trail_paths(trail_pos, run.box))
                a["trails"].set_segments(_trail_paths(trail_pos, run.box))
                a["trails"].set_color(_hue(fr.heading))
            if self.want_edges:
                edges = geometry.interaction_edges(run, fr.position)
                if edges is not None:
                    edges_drawn = len(edges)
                    a["edges"].set_data(*_polyline(_edge_segments(fr.position, edges,
                                                                  run.box)))
            pos, u, v, colours = _arrow_data(run, fr, self.view)
            a["dots"].set_offsets(pos)
            a["dots"].set_color(colours)
            a["arrows"].set_offsets(pos)
            a["arrows"].set_UVC(u, v)
            a["arrows"].set_color(colours)
            agents = len(a["arrows"].U)
        else:
            image, coarse = _field_data(fr, self.mode, self.view)
            a["image"].set_data(image.T)
            if first and self.mode == "density" and image.count():
                lo, hi = float(image.min()), float(image.max())
                a["image"].set_clim(lo, max(hi, lo * 1.01))
            a["coarse"].set_UVC(*coarse)
            agents = len(fr.position)
        if lead is not None:
            a["leader"].set_offsets(lead.leader[None, :])
            if lead.targets is not None:
                a["targets"].set_offsets(lead.targets)
                a["offsets"].set_segments(np.stack(
                    [np.repeat(lead.leader[None, :], len(lead.targets), 0), lead.targets],
                    axis=1))
        name = run.name
        a["title"].set_text(f"{name}: N = {run.n_agents}, t = {fr.time:.4g} "
                            f"(step {fr.step})")
        return SnapshotInfo(k, fr.step, fr.time, self.mode, agents, edges_drawn, trails_drawn)

    def rgb(self) -> np.ndarray:
        """The drawn frame as (H, W, 3) uint8, by blitting: the axes, labels, colour bar
        and static overlays are rendered once, then only the moving artists per frame."""
        canvas = self.fig.canvas
        moving = sorted(self.artists.values(), key=lambda art: art.get_zorder())
        if self._background is None:
            for art in moving:
                art.set_animated(True)
            canvas.draw()
            self._background = canvas.copy_from_bbox(self.fig.bbox)
        canvas.restore_region(self._background)
        for art in moving:
            art.axes.draw_artist(art)
        return np.asarray(canvas.buffer_rgba())[:, :, :3].copy()

    def _build(self, obst: geometry.Obstacles | None) -> None:
        from matplotlib.collections import LineCollection
        from matplotlib.ticker import MaxNLocator

        fig, run, a = self.fig, self.run, self.artists
        fig.clear()
        ax = fig.add_axes((0.1, 0.08, 0.7, 0.84))
        cax = fig.add_axes((0.82, 0.08, 0.025, 0.84))
        x0, x1, y0, y1 = self.view
        n = run.n_agents
        if self.mode == "arrows":
            _heading_colourbar(cax)
            if self.opts.trails is not None:
                a["trails"] = ax.add_collection(LineCollection(
                    [], linewidths=0.8, alpha=0.55, zorder=1))
            if self.want_edges:
                # one line broken by NaNs, not a LineCollection: thousands of edges would
                # cost a Path object each (most of a 10^3-agent snapshot's drawing time)
                (a["edges"],) = ax.plot([], [], c="0.55", lw=0.6, zorder=2, alpha=0.8)
            dot = 18 if n <= 50 else 6 if n <= 1000 else 2
            zeros = np.zeros(n)
            a["dots"] = ax.scatter(zeros, zeros, s=dot, zorder=3, linewidths=0)
            a["arrows"] = ax.quiver(zeros, zeros, zeros, zeros, angles="xy",
                                    scale_units="xy", scale=1.0,
                                    width=0.004 if n <= 50 else 0.0025, headwidth=3.5,
                                    headlength=4, zorder=4)
        else:
            a["image"], a["coarse"] = _field_artists(ax, cax, self.mode, self.view)
        if obst is not None:
            _draw_obstacles(ax, obst)
        if self.opts.overlays and run.kind == "formation":
            lead = geometry.leaders(run, 0.0)
            assert lead is not None
            ax.plot(lead.path[:, 0], lead.path[:, 1], ls="--", lw=1.0, c="0.35", zorder=1,
                    label="leader path p(t)")
            if lead.targets is not None:
                a["offsets"] = ax.add_collection(LineCollection(
                    [], colors="tab:blue", linewidths=0.6, linestyles=":", zorder=2))
                a["targets"] = ax.scatter(lead.targets[:, 0], lead.targets[:, 1], s=40,
                                          marker="s", fc="none", ec="tab:blue", zorder=3,
                                          label="virtual leaders r_id = p + b_i")
            a["leader"] = ax.scatter([lead.leader[0]], [lead.leader[1]], s=160, marker="*",
                                     c="gold", ec="k", zorder=6, label="p(t)")
            ax.legend(loc="upper right", fontsize=8, framealpha=0.8)
        if run.box is not None:
            from matplotlib.patches import Rectangle

            ax.add_patch(Rectangle((0, 0), run.box, run.box, fill=False, lw=1.2, ec="0.2",
                                   zorder=5))
        ax.set_xlim(x0, x1)
        ax.set_ylim(y0, y1)
        # At most 6 labelled ticks an axis (matplotlib's default draws up to 9 here): the
        # tick labels' layout was a fifth of a 10^3-agent snapshot's drawing.
        ax.xaxis.set_major_locator(MaxNLocator(5))
        ax.yaxis.set_major_locator(MaxNLocator(5))
        ax.set_aspect("equal", adjustable="box")
        ax.set_xlabel("x")
        ax.set_ylabel("y")
        a["title"] = ax.set_title("", fontsize=10)


def view_limits(run: RunData, pos: np.ndarray, trails: np.ndarray | None = None,
                obst: geometry.Obstacles | None = None, lead: geometry.Leaders | None = None
                ) -> tuple[float, float, float, float]:
    """The box, or on the plane everything drawn plus a margin, square."""
    if run.box is not None:
        pad = 0.02 * run.box
        return -pad, run.box + pad, -pad, run.box + pad
    pts = [pos]
    if trails is not None:
        pts.append(trails.reshape(-1, 2))
    if obst is not None:
        pts += [obst.points, np.array([obst.destination])]
        pts += [np.array([[x - r, y - r], [x + r, y + r]]) for x, y, r in obst.discs]
    if lead is not None:
        pts += [lead.path, lead.leader[None, :]]
        if lead.targets is not None:
            pts.append(lead.targets)
    allp = np.vstack([p for p in pts if len(p)])
    allp = allp[np.all(np.isfinite(allp), axis=1)]
    lo, hi = allp.min(axis=0), allp.max(axis=0)
    c, half = (lo + hi) / 2, max(float((hi - lo).max()) / 2, 1e-9) * 1.15
    return c[0] - half, c[0] + half, c[1] - half, c[1] + half


def _hue(heading: np.ndarray) -> np.ndarray:
    """RGBA colours of headings on the cyclic hsv map, -π .. π."""
    from matplotlib import colormaps

    return colormaps["hsv"](np.mod(heading + math.pi, 2 * math.pi) / (2 * math.pi))


def _heading_colourbar(cax: Any) -> None:
    from matplotlib import colormaps
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize

    bar = cax.figure.colorbar(ScalarMappable(Normalize(-math.pi, math.pi),
                                             colormaps["hsv"]), cax=cax)
    bar.set_label("heading (rad)")
    bar.set_ticks([-math.pi, -math.pi / 2, 0, math.pi / 2, math.pi],
                  labels=["−π", "−π/2", "0", "π/2", "π"])


def _arrow_data(run: RunData, fr: Frame, view: tuple[float, float, float, float]
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Positions, arrow components and colours: heading arrows of a fixed length, or
    velocity arrows scaled by the run's top speed."""
    width = view[1] - view[0]
    pos, n = fr.position, len(fr.position)
    length = width * (0.035 if n <= 50 else 0.02 if n <= 1000 else 0.012)
    if fr.velocity is not None:
        top = _top_speed(run, fr)
        scale = length * 1.6 / top if top > 0 else 0.0
        u, v = fr.velocity[:, 0] * scale, fr.velocity[:, 1] * scale
    else:
        u, v = length * np.cos(fr.heading), length * np.sin(fr.heading)
    return pos, u, v, _hue(fr.heading)


def _top_speed(run: RunData, fr: Frame) -> float:
    """The largest speed observed over the run (so arrows compare across frames and a
    group at rest draws short arrows), else this frame's."""
    observed = run.observables.get("speed_max")
    if observed is not None and np.isfinite(observed).any():
        return float(np.nanmax(observed))
    speed = np.hypot(fr.velocity[:, 0], fr.velocity[:, 1]) if fr.velocity is not None else []
    return float(np.max(speed)) if len(speed) else 0.0


def _edge_segments(pos: np.ndarray, edges: np.ndarray, box: float | None) -> np.ndarray:
    """(S, 2, 2) segments; an edge across the seam of the box is drawn at both ends."""
    if len(edges) == 0:
        return np.zeros((0, 2, 2))
    a, b = pos[edges[:, 0]], pos[edges[:, 1]]
    d = geometry.displacement(a, b, box)
    segs = [np.stack([a, a + d], axis=1)]
    if box is not None:
        wrapped = np.any(np.abs(b - a - d) > 1e-12, axis=1)
        segs.append(np.stack([b[wrapped], b[wrapped] - d[wrapped]], axis=1))
    return np.concatenate(segs)


def _polyline(segments: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(S, 2, 2) segments as the x and y of one line, a NaN after each segment."""
    pts = np.concatenate([segments, np.full((len(segments), 1, 2), np.nan)], axis=1)
    return pts[:, :, 0].ravel(), pts[:, :, 1].ravel()


def _trails(run: RunData, k: int, window: int) -> np.ndarray:
    start = 0 if window == 0 else max(0, k - window)
    return run.positions(start, k + 1)


def _trail_paths(trails: np.ndarray, box: float | None) -> np.ndarray:
    """(n, F, 2) paths, broken (NaN) where an agent wraps round the periodic box."""
    paths = np.transpose(trails, (1, 0, 2)).copy()
    if box is not None and paths.shape[1] > 1:
        jump = np.any(np.abs(np.diff(paths, axis=1)) > box / 2, axis=2)
        paths[:, 1:][jump] = np.nan
    return paths


def _field_artists(ax: Any, cax: Any, mode: str, view: tuple[float, float, float, float]
                   ) -> tuple[Any, Any]:
    from matplotlib.colors import LogNorm

    x0, x1, y0, y1 = view
    blank = np.ma.masked_all((FIELD_BINS, FIELD_BINS))
    if mode == "density":
        im = ax.imshow(blank, origin="lower", extent=(x0, x1, y0, y1), cmap="magma",
                       norm=LogNorm(1.0, 10.0), interpolation="nearest", aspect="auto")
        label = "agents per unit area"
    else:
        im = ax.imshow(blank, origin="lower", extent=(x0, x1, y0, y1), cmap="viridis",
                       vmin=0, vmax=1, interpolation="nearest", aspect="auto")
        label = "local polarization"
    cax.figure.colorbar(im, cax=cax).set_label(label)
    # empty cells show the background: black (no density) under white arrows, or grey
    # (no polarization defined) under black arrows
    ax.set_facecolor("black" if mode == "density" else "0.82")
    m = COARSE_ARROWS
    xe, ye = np.linspace(x0, x1, m + 1), np.linspace(y0, y1, m + 1)
    xc, yc = np.meshgrid((xe[:-1] + xe[1:]) / 2, (ye[:-1] + ye[1:]) / 2, indexing="ij")
    zeros = np.zeros(m * m)
    coarse = ax.quiver(xc.ravel(), yc.ravel(), zeros, zeros,
                       color="white" if mode == "density" else "black", angles="xy",
                       scale_units="xy", scale=1.0, width=0.003, alpha=0.9, zorder=4,
                       minlength=0)  # an empty cell draws nothing, not a dot
    return im, coarse


def _field_data(fr: Frame, mode: str, view: tuple[float, float, float, float]
                ) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]:
    """The density (agents per unit area) or local polarization on FIELD_BINS cells, and
    the mean heading on a COARSE_ARROWS grid (zero where no agent is)."""
    x0, x1, y0, y1 = view
    pos, extent = fr.position, [[x0, x1], [y0, y1]]
    c, s = np.cos(fr.heading), np.sin(fr.heading)
    counts, _, _ = np.histogram2d(pos[:, 0], pos[:, 1], bins=FIELD_BINS, range=extent)
    if mode == "density":
        cell = ((x1 - x0) / FIELD_BINS) * ((y1 - y0) / FIELD_BINS)
        image = np.ma.masked_equal(counts, 0) / cell
    else:
        sc, _, _ = np.histogram2d(pos[:, 0], pos[:, 1], bins=FIELD_BINS, range=extent,
                                  weights=c)
        ss, _, _ = np.histogram2d(pos[:, 0], pos[:, 1], bins=FIELD_BINS, range=extent,
                                  weights=s)
        with np.errstate(invalid="ignore", divide="ignore"):
            image = np.ma.masked_invalid(np.hypot(sc, ss) / counts)
    m = COARSE_ARROWS
    cc, _, _ = np.histogram2d(pos[:, 0], pos[:, 1], bins=m, range=extent)
    mc, _, _ = np.histogram2d(pos[:, 0], pos[:, 1], bins=m, range=extent, weights=c)
    ms, _, _ = np.histogram2d(pos[:, 0], pos[:, 1], bins=m, range=extent, weights=s)
    step = (x1 - x0) / m * 0.8
    norm = np.maximum(cc, 1)
    return image, ((mc / norm * step).ravel(), (ms / norm * step).ravel())


def _draw_obstacles(ax: Any, obst: geometry.Obstacles) -> None:
    from matplotlib.patches import Circle

    if len(obst.points):
        ax.scatter(obst.points[:, 0], obst.points[:, 1], s=14, marker="o", c="0.15",
                   zorder=3, label="obstacles")
    for x, y, r in obst.discs:
        ax.add_patch(Circle((x, y), r, fc="0.6", ec="0.15", zorder=2))
    ax.scatter([obst.destination[0]], [obst.destination[1]], s=160, marker="*", c="red",
               ec="k", zorder=6, label="destination")
    ax.legend(loc="upper right", fontsize=8, framealpha=0.8)
