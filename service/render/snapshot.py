"""One frame drawn as the papers draw it, in the plane or in 3D space.

Small N: each agent an arrow along its heading (Vicsek) or its velocity (the double
integrators and M4, length relative to the fastest agent of the frame), coloured by
heading; the overlays the model's card names (`geometry`): the interaction edges,
obstacles and the destination (M3), the virtual leader, its path and the formation
offsets b_i to each agent's virtual leader r_id (M4), marked agents (JLM's leader); the
periodic box. Large N (above `FIELD_ABOVE` agents, where arrows are a blur): a density or
local-polarization field on a grid, with the mean heading as a coarse arrow field.

3D runs are drawn through the fixed orthographic camera of `projection`: every point,
segment and vector above is projected, agents are coloured by the azimuth of their
heading and shaded by depth (far ones first, paler, smaller), the periodic cube or the
box around everything drawn is a wireframe with its hidden edges dashed, M3's spheres
are their projected discs, and a field is the density or polarization seen through the
depth.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from . import geometry
from .errors import RenderInputError
from .fields import field_artists, field_data
from .figure import check_size
from .projection import Camera, box_corners, box_edges, fogged, marker_scale, nearness
from .run_data import Frame, RunData

FIELD_ABOVE = 5000  # agents: arrows beyond this are unreadable at any picture size
EDGES_MAX_AGENTS = 200  # edges drawn by default up to here (the papers' N; denser is a blur)
TARGETS_MAX_AGENTS = 200  # M4 F1: each virtual leader and offset up to here, else their outline
Field = Literal["auto", "arrows", "density", "polarization"]
FIELDS: tuple[str, ...] = ("auto", "arrows", "density", "polarization")


@dataclass
class SnapshotOptions:
    """What to draw (shared by the CLI, the HTTP routes and movies)."""

    width: int = 800
    height: int = 800
    field: Field = "auto"
    edges: bool | None = None  # None: at N <= EDGES_MAX_AGENTS when the card draws edges
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


@dataclass(frozen=True)
class View:
    """What a picture spans: the world box lo..hi (the periodic box, or everything drawn
    with a margin), the screen limits around its picture, and in 3D its depth range."""

    lo: np.ndarray  # (dim,)
    hi: np.ndarray
    limits: tuple[float, float, float, float]  # x0, x1, y0, y1 on the screen
    far: float = 0.0  # the farthest and nearest depth of the box (3D)
    near: float = 0.0


def draw_snapshot(fig: Any, run: RunData, k: int, opts: SnapshotOptions,
                  view: View | None = None) -> SnapshotInfo:
    """Draw frame k onto `fig` (cleared first). `view` fixes what the picture spans."""
    return Scene(fig, run, opts, view).draw(k)


class Scene:
    """A figure drawn once and then moved frame to frame (a movie): the first `draw`
    builds the axes and artists, later ones only replace their data, which is several
    times cheaper than drawing the axes anew."""

    def __init__(self, fig: Any, run: RunData, opts: SnapshotOptions,
                 view: View | None = None):
        opts.check()
        self.fig, self.run, self.opts, self.view = fig, run, opts, view
        self.camera = Camera(run.dimension)
        self.mode = opts.field
        if self.mode == "auto":
            self.mode = "density" if run.n_agents > FIELD_ABOVE else "arrows"
        if self.mode != "arrows" and opts.trails is not None:
            raise RenderInputError(f"trails are drawn only with arrows (N <= {FIELD_ABOVE}, "
                                   "or field=arrows)", loc="trails")
        drawing = run.drawing
        self.want_edges = self.mode == "arrows" and (opts.edges if opts.edges is not None else (
            run.n_agents <= EDGES_MAX_AGENTS and "edges" in drawing.overlays
            and not drawing.graph_edges_left_out))
        # agents ringed where they are (JLM's leader rule, eq. 22: agent 0)
        self.marked = (geometry.marked(run) if self.mode == "arrows" and opts.overlays
                       else None)
        n = run.n_agents
        self.each_target = n <= TARGETS_MAX_AGENTS
        self.dot = 18 if n <= 50 else 6 if n <= 1000 else 2  # marker area, points^2
        self.artists: dict[str, Any] = {}  # everything that changes from frame to frame
        self._background: Any = None

    def draw(self, k: int) -> SnapshotInfo:
        run, opts, cam = self.run, self.opts, self.camera
        fr = run.frame(k)
        obst = geometry.obstacles(run) if opts.overlays else None
        lead = geometry.leaders(run, k) if opts.overlays else None
        trail_pos = _trails(run, k, opts.trails) if opts.trails is not None else None
        if self.view is None:
            self.view = make_view(run, drawn_points(fr.position, trail_pos, obst, lead))
        first = not self.artists
        if first:
            self._build(obst, lead)
        a = self.artists
        edges_drawn = trails_drawn = 0
        if self.mode == "arrows":
            colours = _hue(fr.azimuth)
            near = None
            if cam.is_3d:
                near = nearness(cam.depth(fr.position), self.view.far, self.view.near)
                colours = fogged(colours, near)
            if trail_pos is not None:
                paths = _trail_paths(trail_pos, run.box)
                trails_drawn = len(paths)
                a["trails"].set_segments(cam.screen(paths))
                a["trails"].set_color(colours)
            if self.want_edges:
                edges = geometry.interaction_edges(run, fr.position)
                if edges is not None:
                    edges_drawn = len(edges)
                    a["edges"].set_data(*_polyline(cam.screen(
                        _edge_segments(fr.position, edges, run.box))))
            pos, uv = _arrow_data(run, fr, self.view, cam)
            if near is not None:  # far agents first: the near ones are drawn over them
                order = np.argsort(near, kind="stable")
                pos, uv, colours = pos[order], uv[order], colours[order]
                a["dots"].set_sizes(self.dot * marker_scale(near[order]))
            a["dots"].set_offsets(pos)
            a["dots"].set_color(colours)
            a["arrows"].set_offsets(pos)
            a["arrows"].set_UVC(uv[:, 0], uv[:, 1])
            a["arrows"].set_color(colours)
            agents = len(a["arrows"].U)
            if self.marked is not None:
                a["marked"].set_offsets(cam.screen(fr.position[self.marked.agents]))
        else:
            image, coarse = field_data(cam.screen(fr.position), fr.directions, self.mode,
                                       self.view.limits, cam)
            im = a["image"]
            if first and self.mode == "density" and image.count():
                lo, hi = float(image.min()), float(image.max())
                im.set_clim(lo, max(hi, lo * 1.01))  # fixed for a movie from here on
            # Coloured here, as RGBA bytes (empty cells transparent): matplotlib then only
            # resamples it, skipping its masked-float normalisation, which was a fifth of
            # a 10^4-agent movie's frame.
            im.set_data(im.cmap(im.norm(image.T), bytes=True))
            a["coarse"].set_UVC(*coarse)
            agents = len(fr.position)
        if lead is not None:
            leader = cam.screen(lead.leader)
            a["leader"].set_offsets(leader[None, :])
            if lead.targets is not None:
                targets = cam.screen(lead.targets)
                if self.each_target:
                    a["targets"].set_offsets(targets)
                    a["offsets"].set_segments(np.stack(
                        [np.repeat(leader[None, :], len(targets), 0), targets], axis=1))
                else:
                    a["outline"].set_data(*_outline(targets).T)
        a["clock"].set_text(f"t = {fr.time:.4g} (step {fr.step})")
        return SnapshotInfo(k, fr.step, fr.time, self.mode, agents, edges_drawn, trails_drawn)

    def rgba(self) -> np.ndarray:
        """The drawn frame as (H, W, 4) uint8, by blitting: the axes, labels, colour bar
        and static overlays are rendered once, then only the moving artists per frame.
        A view of the canvas: valid until the next draw (an encoder copies it anyway)."""
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
        return np.asarray(canvas.buffer_rgba())

    def _build(self, obst: geometry.Obstacles | None, lead: geometry.Leaders | None) -> None:
        from matplotlib.collections import LineCollection

        fig, run, a, cam = self.fig, self.run, self.artists, self.camera
        fig.clear()
        ax = fig.add_axes((0.1, 0.08, 0.7, 0.84))
        cax = fig.add_axes((0.82, 0.08, 0.025, 0.84))
        n = run.n_agents
        if self.mode == "arrows":
            _heading_colourbar(cax, "heading azimuth (rad)" if cam.is_3d
                               else "heading (rad)")
            if self.opts.trails is not None:
                a["trails"] = ax.add_collection(LineCollection(
                    [], linewidths=0.8, alpha=0.55, zorder=1))
            if self.want_edges:
                # one line broken by NaNs, not a LineCollection: thousands of edges would
                # cost a Path object each (most of a 10^3-agent snapshot's drawing time)
                # (lighter in 3D, where the depth adds crossings)
                (a["edges"],) = ax.plot([], [], c="0.55", lw=0.4 if cam.is_3d else 0.6,
                                        zorder=2, alpha=0.45 if cam.is_3d else 0.8)
            zeros = np.zeros(n)
            a["dots"] = ax.scatter(zeros, zeros, s=self.dot, zorder=3, linewidths=0)
            a["arrows"] = ax.quiver(zeros, zeros, zeros, zeros, angles="xy",
                                    scale_units="xy", scale=1.0,
                                    width=0.004 if n <= 50 else 0.0025, headwidth=3.5,
                                    headlength=4, zorder=4)
        else:
            a["image"], a["coarse"] = field_artists(ax, cax, self.mode, self.view.limits,
                                                    cam)
        if self.marked is not None:
            a["marked"] = ax.scatter([], [], s=150, marker="o", fc="none", ec="k", lw=1.2,
                                     zorder=5, label=self.marked.label)
            ax.legend(loc="upper right", fontsize=8, framealpha=0.8)
        if obst is not None:
            _draw_obstacles(ax, obst, cam)
        if lead is not None:
            self._build_leaders(ax, lead)
        x0, x1, y0, y1 = self.view.limits
        ax.set_xlim(x0, x1)
        ax.set_ylim(y0, y1)
        ax.set_aspect("equal", adjustable="box")
        if cam.is_3d:
            _wireframe(ax, self.view, cam, "0.85" if self.mode == "density" else "0.2",
                       "paler and smaller = farther" if self.mode == "arrows"
                       else "each cell: the agents along its line of sight")
        else:
            _plane_frame(ax, run.box, run.drawing.units.get("length"))
        # the run on the left, drawn once; the time on the right, the one text redrawn
        # per movie frame (glyph rendering was a tenth of a frame)
        ax.set_title(f"{run.name}: N = {run.n_agents}", fontsize=10, loc="left")
        a["clock"] = ax.set_title("", fontsize=10, loc="right")

    def _build_leaders(self, ax: Any, lead: geometry.Leaders) -> None:
        """M4's leader path p(t), the leader now and (F1) the virtual leaders r_id with
        the offsets b_i from p(t) to them (moved frame to frame)."""
        from matplotlib.collections import LineCollection

        a, cam = self.artists, self.camera
        path = cam.screen(lead.path)
        ax.plot(path[:, 0], path[:, 1], ls="--", lw=1.0, c="0.35", zorder=1,
                label="leader path p(t)")
        if lead.targets is not None and self.each_target:
            a["offsets"] = ax.add_collection(LineCollection(
                [], colors="tab:blue", linewidths=0.6, linestyles=":", zorder=2))
            targets = cam.screen(lead.targets)
            a["targets"] = ax.scatter(targets[:, 0], targets[:, 1], s=40, marker="s",
                                      fc="none", ec="tab:blue", zorder=3,
                                      label="virtual leaders r_id = p + b_i")
        elif lead.targets is not None:  # thousands of squares would hide the agents
            (a["outline"],) = ax.plot([], [], c="tab:blue", lw=1.2, zorder=4,
                                      label="outline of the virtual leaders r_id")
        leader = cam.screen(lead.leader)
        a["leader"] = ax.scatter([leader[0]], [leader[1]], s=160, marker="*", c="gold",
                                 ec="k", zorder=6, label="p(t)")
        ax.legend(loc="upper right", fontsize=8, framealpha=0.8)


def drawn_points(pos: np.ndarray, trails: np.ndarray | None = None,
                 obst: geometry.Obstacles | None = None,
                 lead: geometry.Leaders | None = None) -> np.ndarray:
    """Every point a picture of these must show, (K, dim), in world coordinates."""
    dim = pos.shape[1]
    pts = [pos]
    if trails is not None:
        pts.append(trails.reshape(-1, dim))
    if obst is not None:
        pts += [obst.points, np.array([obst.destination])]
        pts += [np.array([np.subtract(c, r), np.add(c, r)]) for c, r in obst.discs]
    if lead is not None:
        pts += [lead.path, lead.leader[None, :]]
        if lead.targets is not None:
            pts.append(lead.targets)
    allp = np.vstack([p.reshape(-1, dim) for p in pts if len(p)])
    return allp[np.all(np.isfinite(allp), axis=1)]


def make_view(run: RunData, points: np.ndarray) -> View:
    """The periodic box, or on the plane (in space) the box around `points`; its picture
    padded to a square."""
    dim, cam = run.dimension, Camera(run.dimension)
    if run.box is not None:
        lo, hi = np.zeros(dim), np.full(dim, run.box)
        if dim == 2:
            pad = 0.02 * run.box
            return View(lo, hi, (-pad, run.box + pad, -pad, run.box + pad))
    else:
        lo, hi = points.min(axis=0), points.max(axis=0)
        if dim == 3:  # the wireframe a little away from the agents
            margin = max(float((hi - lo).max()) * 0.04, 1e-9)
            lo, hi = lo - margin, hi + margin
    if dim == 2:
        corners, grow = np.array([lo, hi]), 1.15
    else:
        corners, grow = cam.screen(box_corners(lo, hi)), 1.08
    slo, shi = corners.min(axis=0), corners.max(axis=0)
    c, half = (slo + shi) / 2, max(float((shi - slo).max()) / 2, 1e-9) * grow
    limits = (c[0] - half, c[0] + half, c[1] - half, c[1] + half)
    if dim == 2:
        return View(lo, hi, limits)
    depth = cam.depth(box_corners(lo, hi))
    return View(lo, hi, limits, float(depth.min()), float(depth.max()))


def _plane_frame(ax: Any, box: float | None, unit: str | None) -> None:
    """The periodic box and the x, y axes of a 2D picture (in the model's length unit)."""
    from matplotlib.ticker import MaxNLocator

    if box is not None:
        from matplotlib.patches import Rectangle

        ax.add_patch(Rectangle((0, 0), box, box, fill=False, lw=1.2, ec="0.2", zorder=5))
    # At most 6 labelled ticks an axis (matplotlib's default draws up to 9 here): the
    # tick labels' layout was a fifth of a 10^3-agent snapshot's drawing.
    ax.xaxis.set_major_locator(MaxNLocator(5))
    ax.yaxis.set_major_locator(MaxNLocator(5))
    ax.set_xlabel(f"x ({unit})" if unit else "x")
    ax.set_ylabel(f"y ({unit})" if unit else "y")


def _wireframe(ax: Any, view: View, cam: Camera, colour: str, depth_note: str) -> None:
    """The box lo..hi of a 3D picture: its visible edges solid, hidden ones dashed, each
    axis named with its range beside one edge; the screen axes carry no ticks (screen
    coordinates mean nothing to a reader), the camera is said under the picture."""
    segments, hidden = box_edges(view.lo, view.hi, cam)
    for seg, back in zip(cam.screen(segments), hidden, strict=True):
        ax.plot(seg[:, 0], seg[:, 1], c=colour, lw=0.9, ls=":" if back else "-",
                zorder=5 if not back else 0.5)
    lo, hi = view.lo, view.hi
    mid = (lo + hi) / 2
    # an edge along each axis on the box's outline (for the default camera: the front
    # bottom edge along x, the right bottom edge along y, the left front edge along z)
    for axis, at in (("x", [mid[0], lo[1], lo[2]]), ("y", [hi[0], mid[1], lo[2]]),
                     ("z", [lo[0], lo[1], mid[2]])):
        i = "xyz".index(axis)
        x, y = cam.screen(np.array(at))
        ax.annotate(f"{axis} {lo[i]:.3g} … {hi[i]:.3g}", (x, y),
                    xytext=(0, -5) if i < 2 else (-5, 0), textcoords="offset points",
                    fontsize=8, color=colour, rotation=0 if i < 2 else 90,
                    ha="center" if i < 2 else "right", va="top" if i < 2 else "center",
                    zorder=6)
    ax.set_xticks([])
    ax.set_yticks([])
    for spine in ax.spines.values():
        spine.set_visible(False)
    ax.text(0.5, -0.03, f"{cam.describe()}; {depth_note}", transform=ax.transAxes,
            ha="center", va="top", fontsize=8, color="0.3")


def _hue(angle: np.ndarray) -> np.ndarray:
    """RGBA colours of heading angles on the cyclic hsv map, -π .. π."""
    from matplotlib import colormaps

    return colormaps["hsv"](np.mod(angle + math.pi, 2 * math.pi) / (2 * math.pi))


def _heading_colourbar(cax: Any, label: str) -> None:
    from matplotlib import colormaps
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize

    bar = cax.figure.colorbar(ScalarMappable(Normalize(-math.pi, math.pi),
                                             colormaps["hsv"]), cax=cax)
    bar.set_label(label)
    bar.set_ticks([-math.pi, -math.pi / 2, 0, math.pi / 2, math.pi],
                  labels=["−π", "−π/2", "0", "π/2", "π"])


def _arrow_data(run: RunData, fr: Frame, view: View, cam: Camera
                ) -> tuple[np.ndarray, np.ndarray]:
    """The agents' pictures (N, 2) and their arrows (N, 2): heading arrows of a fixed
    length, or velocity arrows scaled by the run's top speed, as seen on the screen (a
    3D arrow pointing at the viewer is short)."""
    width = view.limits[1] - view.limits[0]
    n = len(fr.position)
    length = width * (0.035 if n <= 50 else 0.02 if n <= 1000 else 0.012)
    if fr.velocity is not None:
        top = _top_speed(run, fr)
        arrows = fr.velocity * (length * 1.6 / top if top > 0 else 0.0)
    else:
        arrows = length * fr.directions
    return cam.screen(fr.position), cam.screen(arrows)


def _top_speed(run: RunData, fr: Frame) -> float:
    """The largest speed observed over the run (so arrows compare across frames and a
    group at rest draws short arrows), else this frame's."""
    observed = run.observables.get("speed_max")
    if observed is not None and np.isfinite(observed).any():
        return float(np.nanmax(observed))
    if fr.velocity is None or not len(fr.velocity):
        return 0.0
    return float(np.sqrt((fr.velocity * fr.velocity).sum(axis=1)).max())


def _edge_segments(pos: np.ndarray, edges: np.ndarray, box: float | None) -> np.ndarray:
    """(S, 2, dim) segments; an edge across the seam of the box is drawn at both ends."""
    if len(edges) == 0:
        return np.zeros((0, 2, pos.shape[1]))
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
    """(n, F, dim) paths, broken (NaN) where an agent wraps round the periodic box."""
    paths = np.transpose(trails, (1, 0, 2)).copy()
    if box is not None and paths.shape[1] > 1:
        jump = np.any(np.abs(np.diff(paths, axis=1)) > box / 2, axis=2)
        paths[:, 1:][jump] = np.nan
    return paths


def _outline(points: np.ndarray) -> np.ndarray:
    """The convex hull of (K, 2) points as a closed polyline (K' + 1, 2); points on a line
    give the segment between the two ends."""
    from scipy.spatial import ConvexHull, QhullError

    try:
        ring = points[ConvexHull(points).vertices]
    except QhullError:  # fewer than three points, or all on one line
        order = np.lexsort((points[:, 1], points[:, 0]))
        ring = points[[order[0], order[-1]]]
    return np.vstack([ring, ring[:1]])


def _draw_obstacles(ax: Any, obst: geometry.Obstacles, cam: Camera) -> None:
    """M3's point obstacles, its discs (spheres in 3D: their projected discs, seen
    through) and the destination."""
    from matplotlib.patches import Circle

    if len(obst.points):
        pts = cam.screen(obst.points)
        ax.scatter(pts[:, 0], pts[:, 1], s=14 if len(pts) <= 100 else 5, marker="o",
                   c="0.15", zorder=3, label="obstacles")
    for centre, r in obst.discs:
        ax.add_patch(Circle(tuple(cam.screen(np.asarray(centre))), r, fc="0.6", ec="0.15",
                            alpha=0.45 if cam.is_3d else 1.0, zorder=2))
    dest = cam.screen(np.asarray(obst.destination))
    ax.scatter([dest[0]], [dest[1]], s=160, marker="*", c="red", ec="k", zorder=6,
               label="destination")
    ax.legend(loc="upper right", fontsize=8, framealpha=0.8)
