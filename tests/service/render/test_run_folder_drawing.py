"""What drawing a run needs is in its run folder (trajectory.h5's drawing group, written by
the worker): the engine's own fixed graph and virtual leaders, read back by the renderer
without the engine; a folder written before the group existed is still drawn from what it
has; a fixed graph too large to keep is said to be left out."""

from __future__ import annotations

import shutil

import h5py
import numpy as np
import pytest

from flocklab.service import h5md
from flocklab.service.render import geometry
from flocklab.service.render.errors import RenderInputError
from flocklab.service.render.figure import new_figure
from flocklab.service.render.run_data import RunData
from flocklab.service.render.snapshot import SnapshotOptions, draw_snapshot
from tests.service.render.conftest import FAMILIES, preset_scenario, run_to


def test_virtual_leaders_are_the_engines(runs):
    """Every frame's leader and virtual leaders r_id = p(t) + b_i(t) as the engine's own
    path and offset schedule give them, through sim1's quarter turn (t = 8 .. 12)."""
    from flocklab.kernels.models.formation.path import make_path
    from flocklab.kernels.models.formation.schedule import OffsetSchedule
    from flocklab.kernels.space.initial import initial_state

    run = RunData(runs["formation_F1"])
    sc = run.scenario
    m = sc.model
    path = make_path(m.path, initial_state(sc).positions.mean(axis=0))
    schedule = OffsetSchedule(m.formation, m.schedule, sc.n_agents, sc.neighbours.radius,
                              sc.dimension)
    times = run.frame_index[1]
    assert any(8.0 < t < 12.0 for t in times)  # frames inside the formation change
    for k, t in enumerate(times):
        lead = geometry.leaders(run, k)
        assert lead is not None and lead.targets is not None
        np.testing.assert_array_equal(lead.leader, path.position(t))
        np.testing.assert_allclose(lead.targets, path.position(t)[None, :] + schedule.at(t),
                                   rtol=0, atol=1e-12)
    assert geometry.leaders(RunData(runs["formation_F2"]), 0).targets is None


def test_fixed_graph_is_the_engines(runs):
    from flocklab.kernels.models.flocking.topology import build_edges

    run = RunData(runs["flocking_fixed"])
    u, v = build_edges(run.scenario.model.graph, run.n_agents, run.scenario.seed)
    edges = geometry.interaction_edges(run, run.frame(0).position)
    np.testing.assert_array_equal(edges, np.column_stack([u, v]))
    assert len(edges) == run.summary["graph"]["edges"]


def _as_written_before(folder, tmp_path):
    """A copy of a run folder as main wrote it before the drawing group: the same files
    and H5MD layout (compared by hand against a folder main's execute_to_dir wrote),
    without that group."""
    old = tmp_path / folder.name
    shutil.copytree(folder, old)
    with h5py.File(old / "trajectory.h5", "a") as f:
        del f[h5md.DRAWING]
    return old


@pytest.mark.parametrize("family", list(FAMILIES))
def test_a_folder_written_before_is_drawn(runs, tmp_path, family):
    """The card's facts from the schemas, the parameters' overlays as before, the leader
    where its observables put it; what only the engine knew (a fixed graph, the virtual
    leaders) is left out of the picture, not guessed."""
    new = RunData(runs[family])
    old = RunData(_as_written_before(runs[family], tmp_path))
    a, b = new.drawing, old.drawing
    assert (b.inclusive, b.units, b.default_plots, b.overlays) == (
        a.inclusive, a.units, a.default_plots, a.overlays)
    k = old.n_frames - 1
    info = draw_snapshot(new_figure(300, 300), old, k, SnapshotOptions(300, 300, edges=True))
    assert info.agents_drawn == old.n_agents
    if family == "flocking_fixed":
        assert info.edges_drawn == 0
    else:
        fresh = draw_snapshot(new_figure(300, 300), new, k, SnapshotOptions(300, 300,
                                                                            edges=True))
        assert info.edges_drawn == fresh.edges_drawn
    was, now = geometry.obstacles(old), geometry.obstacles(new)
    assert (was is None) == (now is None) == (family != "flocking_obstacles")
    if now is not None:
        np.testing.assert_array_equal(was.points, now.points)
        assert (was.discs, was.destination) == (now.discs, now.destination)
    lead = geometry.leaders(old, k)
    if family.startswith("formation"):
        # the frames fall on observation times: the observed leader is the engine's p(t)
        np.testing.assert_allclose(lead.leader, geometry.leaders(new, k).leader, atol=1e-9)
        assert lead.targets is None
    else:
        assert lead is None


def test_a_fixed_graph_too_large_to_keep(tmp_path, taichi_cpu, monkeypatch):
    """Past MAX_STORED_EDGES the graph is counted, not stored: drawing it by default
    leaves the edges out; asking for them is an error that says why."""
    monkeypatch.setattr(h5md, "MAX_STORED_EDGES", 5)
    name, over = FAMILIES["flocking_fixed"]
    run = RunData(run_to(tmp_path / "big", preset_scenario(name, over)))
    assert run.drawing.graph_edges_left_out == run.summary["graph"]["edges"] > 5
    info = draw_snapshot(new_figure(300, 300), run, 0, SnapshotOptions(300, 300))
    assert info.edges_drawn == 0 and info.agents_drawn == run.n_agents
    with pytest.raises(RenderInputError, match=r"fixed graph has \d+ edges, more than a run "
                       "folder keeps") as err:
        draw_snapshot(new_figure(300, 300), run, 0, SnapshotOptions(300, 300, edges=True))
    assert err.value.loc == "edges"


@pytest.mark.parametrize("family", list(FAMILIES))
def test_trajectory_units_are_the_cards(runs, family):
    run = RunData(runs[family])
    time_unit, length_unit = type(run.scenario.model).units
    with h5py.File(run.trajectory_path) as f:
        position = f["particles/swarm/position"]
        assert position["value"].attrs.get("unit") == length_unit
        assert position["time"].attrs.get("unit") == time_unit
        assert ("units" in f["h5md"].get("modules", {})) == bool(time_unit or length_unit)
