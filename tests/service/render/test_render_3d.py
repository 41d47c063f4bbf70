"""Pictures of real 3D runs (space.dimension = 3) of every model family: valid images of
the requested size, not blank, every agent drawn where the camera puts it, far agents
first and paler, the interaction edges counted against brute force in 3D, M3's spheres
as discs of their radius, M4's virtual leaders; trails, movies, a 10^5-agent field and
the command line."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from flocklab.service.render.figure import new_figure, save
from flocklab.service.render.projection import Camera
from flocklab.service.render.run_data import RunData
from flocklab.service.render.snapshot import SnapshotOptions, draw_snapshot
from tests.service.render.conftest import (
    FAMILIES_3D,
    assert_picture,
    preset_scenario,
    read_image,
    run_to,
)

FAMILIES = [*FAMILIES_3D, "flocking_obstacles"]


def brute_force_edges_3d(pos: np.ndarray, r: float, box: float | None,
                         inclusive: bool) -> int:
    d = pos[:, None, :] - pos[None, :, :]
    if box is not None:
        d -= box * np.round(d / box)
    dist = np.sqrt((d * d).sum(axis=-1))
    close = dist <= r if inclusive else dist < r
    return int(np.triu(close, 1).sum())


def dots(fig) -> tuple[np.ndarray, np.ndarray]:
    """The agents' markers as drawn: (N, 2) offsets and (N, 4) colours, in draw order."""
    from matplotlib.collections import PathCollection

    scatter = next(c for c in fig.axes[0].collections
                   if isinstance(c, PathCollection) and c.get_label().startswith("_"))
    return np.asarray(scatter.get_offsets()), scatter.get_facecolors()


@pytest.mark.slow_cases("vicsek", "flocking_fixed")
@pytest.mark.parametrize("family", FAMILIES)
def test_snapshot_of_every_family_in_3d(runs_3d, tmp_path, family):
    run = RunData(runs_3d[family])
    assert run.dimension == 3
    out = tmp_path / f"{family}.png"
    fig = new_figure(640, 480)
    info = draw_snapshot(fig, run, run.pick_frame(), SnapshotOptions(640, 480, edges=True))
    save(fig, out)
    assert_picture(read_image(out), 640, 480)
    assert info.mode == "arrows" and info.frame == run.n_frames - 1
    assert info.agents_drawn == run.n_agents
    fr = run.frame(info.frame)
    assert fr.position.shape == (run.n_agents, 3)
    # every agent where the camera puts it, the farthest first and the nearest last
    cam = Camera(3)
    drawn, colours = dots(fig)
    depth = cam.depth(fr.position)
    order = np.argsort(depth, kind="stable")
    np.testing.assert_allclose(drawn, cam.screen(fr.position)[order])
    far, near = colours[0, :3], colours[-1, :3]
    if depth.max() - depth.min() > 1e-6 * np.abs(depth).max():
        assert far.min() > near.min(), (far, near)  # mixed towards white: paler
    if run.kind == "flocking" and run.doc["model"]["topology"] == "fixed":
        assert info.edges_drawn == run.summary["graph"]["edges"]
    else:
        assert info.edges_drawn == brute_force_edges_3d(
            fr.position, run.scenario.neighbours.radius, run.box, run.scenario.inclusive)
    assert info.edges_drawn > 0 or run.kind == "formation"


def test_3d_overlays(runs_3d):
    """M3: the point obstacles, each sphere as the disc of its radius about its centre's
    picture, the destination; M4 F1: a virtual leader per agent, the leader at p(t)."""
    from matplotlib.patches import Circle

    cam = Camera(3)
    run = RunData(runs_3d["flocking_obstacles"])
    fig = new_figure(400, 400)
    draw_snapshot(fig, run, run.n_frames - 1, SnapshotOptions(400, 400))
    ax = fig.axes[0]
    labels = {t.get_text() for t in ax.get_legend().get_texts()}
    assert labels == {"obstacles", "destination"}
    model = run.scenario.model
    points = next(c for c in ax.collections if c.get_label() == "obstacles")
    np.testing.assert_allclose(points.get_offsets(), cam.screen(np.array(model.obstacles)))
    discs = [p for p in ax.patches if isinstance(p, Circle)]
    assert len(discs) == len(model.discs) == 1
    np.testing.assert_allclose(discs[0].center, cam.screen(np.array(model.discs[0].center)))
    assert discs[0].radius == model.discs[0].radius
    dest = next(c for c in ax.collections if c.get_label() == "destination")
    np.testing.assert_allclose(dest.get_offsets()[0], cam.screen(np.array(model.destination)))

    run = RunData(runs_3d["formation_F1"])
    fig = new_figure(400, 400)
    k = run.pick_frame(time=10.0)
    draw_snapshot(fig, run, k, SnapshotOptions(400, 400))
    ax = fig.axes[0]
    targets = next(c for c in ax.collections if c.get_label().startswith("virtual"))
    assert len(targets.get_offsets()) == run.n_agents
    obs = run.observables
    i = int(np.argmin(np.abs(obs["time"] - run.frame(k).time)))
    leader = np.array([obs["leader_x"][i], obs["leader_y"][i], obs["leader_z"][i]])
    star = next(c for c in ax.collections if c.get_label() == "p(t)")
    np.testing.assert_allclose(star.get_offsets()[0], cam.screen(leader), atol=1e-9)


def test_3d_trails_and_fields(runs_3d, tmp_path):
    run = RunData(runs_3d["flocking_obstacles"])
    fig = new_figure(500, 500)
    info = draw_snapshot(fig, run, 100, SnapshotOptions(500, 500, trails=0))
    assert info.trails_drawn == run.n_agents
    save(fig, tmp_path / "trails.png")
    assert_picture(read_image(tmp_path / "trails.png"), 500, 500)
    run = RunData(runs_3d["vicsek"])
    for field in ("density", "polarization"):
        fig = new_figure(300, 300)
        info = draw_snapshot(fig, run, 0, SnapshotOptions(300, 300, field=field))
        assert info.mode == field and info.agents_drawn == run.n_agents
        save(fig, tmp_path / f"{field}.png")
        assert_picture(read_image(tmp_path / f"{field}.png"), 300, 300)


@pytest.fixture(scope="module")
def large_run_3d(tmp_path_factory, taichi_cpu):
    """10^5 agents of the vicsek-3d preset, two steps."""
    sc = preset_scenario("vicsek-3d", {"time": {"steps": 2}, "recording": {"every": 1}})
    assert sc.initial.N == 100_000
    return run_to(tmp_path_factory.mktemp("render-large-3d") / "vicsek-3d", sc)


@pytest.mark.slow
def test_large_3d_run_draws_a_field(large_run_3d, tmp_path):
    run = RunData(large_run_3d)
    for field in ("auto", "polarization"):
        fig = new_figure(800, 800)
        info = draw_snapshot(fig, run, run.pick_frame(), SnapshotOptions(800, 800,
                                                                         field=field))
        assert info.mode == ("density" if field == "auto" else field)
        assert info.agents_drawn == 100_000
        save(fig, tmp_path / f"{field}.png")
        assert_picture(read_image(tmp_path / f"{field}.png"), 800, 800)


def test_3d_movie_mp4_and_gif(runs_3d, tmp_path):
    import imageio.v2 as iio2
    import imageio.v3 as iio

    from flocklab.service.render.movie import write_movie

    run = RunData(runs_3d["formation_F1"])
    n = write_movie(run, tmp_path / "m.mp4", SnapshotOptions(320, 240), fps=10)
    assert n == run.n_frames
    reader = iio2.get_reader(tmp_path / "m.mp4", format="FFMPEG")
    try:
        frames = np.stack([reader.get_data(i) for i in range(reader.count_frames())])
    finally:
        reader.close()
    assert frames.shape[0] == n and frames.shape[1:3] == (240, 320)
    assert frames[0].std() > 10 and np.abs(frames[0].astype(int) - frames[-1]).mean() > 0.5
    write_movie(run, tmp_path / "m.gif", SnapshotOptions(200, 200, trails=3), stride=4)
    gif = iio.imread(tmp_path / "m.gif")
    assert gif.shape[0] == len(range(0, run.n_frames, 4)) and gif.shape[1:3] == (200, 200)


@pytest.mark.slow
def test_cli_renders_a_3d_run(runs_3d, tmp_path):
    folder = runs_3d["vicsek"]
    out = tmp_path / "v.png"
    r = subprocess.run([sys.executable, "-m", "flocklab", "render", str(folder), "--out",
                        str(out), "--trails", "3", "--size", "400x300"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    summary = json.loads(r.stdout)
    assert summary["agents"] == RunData(folder).n_agents and summary["mode"] == "arrows"
    assert_picture(read_image(out), 400, 300)
    r = subprocess.run([sys.executable, "-m", "flocklab", "render", str(folder), "--out",
                        str(tmp_path / "v.gif"), "--movie", "--stride", "3", "--size",
                        "160x160", "--quiet"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["frames"] == len(range(0, RunData(folder).n_frames, 3))
