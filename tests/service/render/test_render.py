"""Pictures of real runs of every model family: valid images of the requested size, not
blank, and (at small N) exactly the run's agents and interaction edges drawn."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

from flocklab.service.render.errors import RenderInputError
from flocklab.service.render.figure import new_figure, save
from flocklab.service.render.plots import draw_observables
from flocklab.service.render.run_data import RunData
from flocklab.service.render.snapshot import SnapshotOptions, draw_snapshot
from tests.service.render.conftest import FAMILIES, assert_picture, read_image


def brute_force_edges(pos: np.ndarray, r: float, box: float | None, inclusive: bool) -> int:
    d = pos[:, None, :] - pos[None, :, :]
    if box is not None:
        d -= box * np.round(d / box)
    dist = np.hypot(d[..., 0], d[..., 1])
    close = dist <= r if inclusive else dist < r
    return int(np.triu(close, 1).sum())


@pytest.mark.slow_cases("vicsek", "flocking_fixed")
@pytest.mark.parametrize("family", list(FAMILIES))
def test_snapshot_of_every_family(runs, tmp_path, family):
    run = RunData(runs[family])
    out = tmp_path / f"{family}.png"
    fig = new_figure(640, 480)
    info = draw_snapshot(fig, run, run.pick_frame(), SnapshotOptions(640, 480, edges=True))
    save(fig, out)
    assert_picture(read_image(out), 640, 480)
    assert info.mode == "arrows"
    assert info.agents_drawn == run.n_agents
    assert info.frame == run.n_frames - 1
    fr = run.frame(info.frame)
    if run.scenario.model.kind == "flocking" and run.scenario.model.topology == "fixed":
        assert info.edges_drawn == run.summary["graph"]["edges"]
    else:
        assert info.edges_drawn == brute_force_edges(
            fr.position, run.scenario.neighbours.radius, run.box, run.scenario.inclusive)


def test_overlays_are_drawn(runs):
    """Obstacles, destination (M3); leader, path, virtual leaders (M4 F1)."""
    run = RunData(runs["flocking_obstacles"])
    fig = new_figure(400, 400)
    draw_snapshot(fig, run, -1 + run.n_frames, SnapshotOptions(400, 400))
    labels = {t.get_text() for t in fig.axes[0].get_legend().get_texts()}
    assert labels == {"obstacles", "destination"}
    n_obstacles = len(run.scenario.model.obstacles)
    assert any(len(c.get_offsets()) == n_obstacles for c in fig.axes[0].collections)

    run = RunData(runs["formation_F1"])
    fig = new_figure(400, 400)
    k = run.pick_frame(time=10.0)
    draw_snapshot(fig, run, k, SnapshotOptions(400, 400))
    labels = {t.get_text() for t in fig.axes[0].get_legend().get_texts()}
    assert labels == {"leader path p(t)", "virtual leaders r_id = p + b_i", "p(t)"}
    targets = next(c for c in fig.axes[0].collections if c.get_label().startswith("virtual"))
    assert len(targets.get_offsets()) == run.n_agents
    leader = np.array([run.observables["leader_x"], run.observables["leader_y"]]).T
    t_obs = run.observables["time"]
    star = next(c for c in fig.axes[0].collections if c.get_label() == "p(t)")
    i = int(np.argmin(np.abs(t_obs - run.frame(k).time)))
    np.testing.assert_allclose(star.get_offsets()[0], leader[i], atol=1e-9)


def test_jlm_leader_is_ringed(tmp_path, taichi_cpu):
    """The leader rule's agent 0 (JLM eq. 22) is marked where it is."""
    from tests.service.render.conftest import preset_scenario, run_to

    run = RunData(run_to(tmp_path / "jlm", preset_scenario("jlm-leader",
                                                          {"time": {"steps": 20}})))
    fig = new_figure(300, 300)
    draw_snapshot(fig, run, run.n_frames - 1, SnapshotOptions(300, 300))
    ring = next(c for c in fig.axes[0].collections if c.get_label().startswith("leader"))
    np.testing.assert_array_equal(ring.get_offsets(), run.frame(run.n_frames - 1).position[:1])
    fig = new_figure(300, 300)
    draw_snapshot(fig, run, 0, SnapshotOptions(300, 300, overlays=False))
    assert fig.axes[0].get_legend() is None


def test_explicit_initial_state_is_drawn(tmp_path, taichi_cpu):
    """A run of examples/obstacles.json (positions given, so no initial.N in its
    scenario.json) is drawn with its 12 agents."""
    from flocklab.schemas import Scenario
    from tests.service.render.conftest import merge, run_to

    example = Path(__file__).resolve().parents[3] / "examples" / "obstacles.json"
    doc = json.loads(example.read_text())
    sc = Scenario.model_validate(merge(doc, {"time": {"steps": 500}}))
    run = RunData(run_to(tmp_path / "m3", sc))
    assert "N" not in run.doc["initial"] and run.n_agents == 12
    fig = new_figure(300, 300)
    info = draw_snapshot(fig, run, run.n_frames - 1, SnapshotOptions(300, 300))
    assert info.agents_drawn == 12


def test_frame_time_and_trails(runs, tmp_path):
    run = RunData(runs["flocking_obstacles"])
    assert run.pick_frame(frame=0) == 0
    assert run.pick_frame(frame=-1) == run.n_frames - 1
    steps, times = run.frame_index
    assert run.pick_frame(time=float(times[3]) + 1e-9) == 3
    with pytest.raises(RenderInputError, match="out of range"):
        run.pick_frame(frame=run.n_frames)
    with pytest.raises(RenderInputError, match="before the first frame"):
        run.pick_frame(time=-1.0)
    fig = new_figure(500, 500)
    info = draw_snapshot(fig, run, 10, SnapshotOptions(500, 500, trails=0))
    assert info.trails_drawn == run.n_agents and info.step == steps[10]
    out = tmp_path / "trails.png"
    save(fig, out)
    assert_picture(read_image(out), 500, 500)


@pytest.mark.parametrize("suffix, magic", [(".svg", b"<?xml"), (".pdf", b"%PDF")])
def test_vector_formats_by_suffix(runs, tmp_path, suffix, magic):
    run = RunData(runs["flocking_switching"])
    fig = new_figure(300, 300)
    draw_snapshot(fig, run, 0, SnapshotOptions(300, 300))
    out = tmp_path / f"s{suffix}"
    save(fig, out)
    assert out.read_bytes().startswith(magic)


@pytest.mark.slow
def test_large_n_draws_a_field_quickly(large_run, tmp_path):
    run = RunData(large_run)
    for field in ("density", "polarization"):
        t0 = time.perf_counter()
        fig = new_figure(800, 800)
        opts = SnapshotOptions(800, 800, field="auto" if field == "density" else field)
        info = draw_snapshot(fig, run, run.pick_frame(), opts)
        out = tmp_path / f"{field}.png"
        save(fig, out)
        elapsed = time.perf_counter() - t0
        assert info.mode == field and info.agents_drawn == 100_000
        assert_picture(read_image(out), 800, 800)
        assert elapsed < 30, elapsed  # the bar is 5 s at 10^6 (bench/render_bench.py)


@pytest.mark.slow  # 10^5-agent runs of four families; Vicsek's large N stays fast above
@pytest.mark.parametrize("family", ["flocking_switching", "flocking_obstacles",
                                    "formation_F1", "formation_F2"])
def test_large_n_of_every_family(large_runs, tmp_path, family):
    """10^5 agents: a density field with the family's overlays; F1's 10^5 virtual leaders
    as their outline, not 10^5 squares over the field."""
    run = RunData(large_runs[family])
    fig = new_figure(800, 800)
    info = draw_snapshot(fig, run, run.pick_frame(), SnapshotOptions(800, 800))
    save(fig, tmp_path / "large.png")
    assert info.mode == "density" and info.agents_drawn == run.n_agents == 100_000
    assert_picture(read_image(tmp_path / "large.png"), 800, 800)
    labels = {t.get_text() for t in fig.axes[0].get_legend().get_texts()} if (
        run.kind != "flocking") else set()
    if family == "formation_F1":
        assert labels == {"leader path p(t)", "outline of the virtual leaders r_id", "p(t)"}
        outline = next(ln for ln in fig.axes[0].get_lines()
                       if ln.get_label().startswith("outline"))
        assert 3 <= len(outline.get_xdata()) < 1000
    elif family == "flocking_obstacles":
        assert labels == {"obstacles", "destination"}


def test_observables_plot_marks_convergence(runs, tmp_path):
    run = RunData(runs["flocking_fixed"])
    conv = run.convergence
    assert "velocity_disagreement" in conv
    fig = new_figure(900, 700)
    names = draw_observables(fig, run, ["velocity_disagreement", "components"], 900, 700)
    assert names == ["velocity_disagreement", "components"]
    first = fig.axes[0]
    marks = [ln for ln in first.get_lines() if np.allclose(ln.get_xdata(), conv[names[0]])]
    assert marks, "no vertical line at the convergence time"
    out = tmp_path / "obs.png"
    save(fig, out)
    assert_picture(read_image(out), 900, 700, min_ink=0.01)
    with pytest.raises(RenderInputError, match="unknown observable"):
        draw_observables(new_figure(300, 300), run, ["nope"], 300, 300)


def test_movie_mp4_and_gif(runs, tmp_path):
    import imageio.v3 as iio

    from flocklab.service.render.movie import write_movie

    run = RunData(runs["formation_F1"])
    seen = []
    n = write_movie(run, tmp_path / "m.mp4", SnapshotOptions(320, 240), fps=10,
                    on_progress=lambda done, total: seen.append((done, total)))
    assert n == run.n_frames and seen[-1] == (n, n)
    import imageio.v2 as iio2

    reader = iio2.get_reader(tmp_path / "m.mp4", format="FFMPEG")
    try:
        count = reader.count_frames()
        frames = np.stack([reader.get_data(i) for i in range(count)])
    finally:
        reader.close()
    assert frames.shape[0] == n and frames.shape[1:3] == (240, 320)
    assert frames[0].std() > 10 and np.abs(frames[0].astype(int) - frames[-1]).mean() > 0.5
    write_movie(run, tmp_path / "m.gif", SnapshotOptions(200, 200), stride=5)
    gif = iio.imread(tmp_path / "m.gif")
    assert gif.shape[0] == len(range(0, run.n_frames, 5)) and gif.shape[1:3] == (200, 200)


@pytest.mark.slow
def test_cli_render_and_its_errors(runs, tmp_path):
    folder = runs["vicsek"]
    out = tmp_path / "v.png"
    cmd = [sys.executable, "-m", "flocklab", "render", str(folder), "--out", str(out),
           "--frame", "2", "--size", "400x300"]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    summary = json.loads(r.stdout)
    assert summary["frame"] == 2 and summary["agents"] == 300
    assert_picture(read_image(out), 400, 300)
    for args, message in [(["--frame", "999"], "out of range"),
                          (["--size", "big"], "WIDTHxHEIGHT"),
                          (["--plot", "nope"], "unknown observable")]:
        r = subprocess.run([*cmd[:5], "--out", str(tmp_path / "x.png"), *args],
                           capture_output=True, text=True, timeout=120)
        assert r.returncode == 2 and message in r.stderr and "Traceback" not in r.stderr
    r = subprocess.run([*cmd[:4], str(tmp_path / "missing"), "--out", str(out)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "no such folder" in r.stderr
    r = subprocess.run([*cmd[:5], "--out", str(tmp_path / "x.bmp")], capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 2 and "unknown picture type" in r.stderr
    # an install without h5py (the plot extra): one line naming the extra
    blocked = ("import sys; sys.modules['h5py'] = None; from flocklab.service.entry import "
               "main; sys.exit(main(sys.argv[1:]))")
    r = subprocess.run([sys.executable, "-c", blocked, *cmd[3:]], capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "h5py is not installed: pip install 'flocklab[plot]'" in r.stderr


def test_trajectory_frames_are_in_agent_order(runs):
    """The renderer reads the H5MD file as written; agent ids are the row order."""
    run = RunData(runs["formation_F2"])
    with h5py.File(run.trajectory_path) as f:
        np.testing.assert_array_equal(f["particles/swarm/position/value"][0],
                                      run.frame(0).position)


@pytest.mark.parametrize("runs_fixture, family, frames", [
    ("runs", "formation_F1", (0, 5, -1)),
    ("runs_3d", "flocking_obstacles", (0, 70, -1)),  # depth order and fog change per frame
])
# Two minutes of 3D drawing; the 2D case stays fast (3D frames: test_render_3d.py).
@pytest.mark.slow_cases("runs_3d-flocking_obstacles-frames1")
def test_movie_frames_match_full_drawings(request, runs_fixture, family, frames):
    """Blitting (axes drawn once, moving artists per frame) gives the full drawing."""
    from flocklab.service.render.movie import _movie_view
    from flocklab.service.render.snapshot import Scene

    run = RunData(request.getfixturevalue(runs_fixture)[family])
    opts = SnapshotOptions(320, 320, trails=2)
    view = _movie_view(run, range(run.n_frames))
    scene = Scene(new_figure(320, 320), run, opts, view)
    for k in frames:
        k %= run.n_frames
        scene.draw(k)
        blitted = scene.rgba()[:, :, :3].copy()
        fig = new_figure(320, 320)
        Scene(fig, run, opts, view).draw(k)
        fig.canvas.draw()
        full = np.asarray(fig.canvas.buffer_rgba())[:, :, :3]
        assert np.abs(full.astype(int) - blitted).mean() < 0.5, k
