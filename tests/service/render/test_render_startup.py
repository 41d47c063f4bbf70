"""`flocklab render`'s start-up: for every model family, the console script's render path
imports neither the pydantic schemas, the engine, scipy nor the service app (what the
picture needs of the model is in the run folder), and its light reading of the run
folder agrees with the validated scenario and the model's card."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from flocklab.service.render import geometry
from flocklab.service.render.run_data import RunData
from tests.service.render.conftest import FAMILIES, assert_picture, read_image

HEAVY = ("flocklab.schemas", "pydantic", "flocklab.kernels", "taichi", "scipy", "fastapi",
         "flocklab.service.cli", "flocklab.service.app")


@pytest.mark.parametrize("family", list(FAMILIES))
def test_render_command_skips_the_heavy_imports(runs, tmp_path, family):
    """The console script's entry (`service.entry:main`) drawing a snapshot with edges and
    the overlays, then the default observables plot, in a fresh interpreter that then
    lists what it imported."""
    snap, plot = tmp_path / "s.png", tmp_path / "o.png"
    folder = str(runs[family])
    code = ("import sys, json; from flocklab.service.entry import main; "
            f"rc = main(['render', {folder!r}, '--out', {str(snap)!r}, "
            "'--edges', '--size', '400x400']); "
            f"rc += main(['render', {folder!r}, '--out', {str(plot)!r}, '--plot']); "
            "print(json.dumps({'rc': rc, 'modules': sorted(sys.modules)}))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0, r.stderr
    lines = r.stdout.strip().splitlines()
    drawn, plotted, report = (json.loads(line) for line in lines[-3:])
    run = RunData(runs[family])
    assert report["rc"] == 0 and drawn["agents"] == run.n_agents
    assert drawn["edges"] > 0 or family.startswith("formation")  # its graph may be empty
    assert plotted["observables"] == [n for n in run.scenario.model.default_plots
                                      if n in run.observables]
    loaded = [m for m in report["modules"] if m.split(".")[0] in {h.split(".")[0] for h in HEAVY}
              and any(m == h or m.startswith(h + ".") for h in HEAVY)]
    assert loaded == [], f"render imported {loaded}"
    assert_picture(read_image(snap), 400, 400)


def test_console_script_passes_other_commands_through(tmp_path):
    from flocklab.service.entry import main

    assert main(["presets"]) == 0
    assert main(["render", str(tmp_path / "missing"), "--out", str(tmp_path / "x.png")]) == 2


@pytest.mark.parametrize("family", list(FAMILIES))
def test_light_scenario_facts_match_the_schemas(runs, family):
    run = RunData(runs[family])
    sc = run.scenario  # validated on demand
    assert (run.kind, run.n_agents, run.inclusive) == (sc.model.kind, sc.n_agents,
                                                       sc.inclusive)
    assert run.box == (float(sc.space.L) if sc.space.kind == "periodic" else None)
    assert run.radius == (float(sc.neighbours.radius) if sc.neighbours else None)
    card, drawing = type(sc.model), run.drawing
    assert drawing.units == {"time": card.units[0], "length": card.units[1]}
    assert (drawing.default_plots, drawing.overlays) == (list(card.default_plots),
                                                        list(card.overlays))


@pytest.mark.parametrize("box", [None, 7.0])
@pytest.mark.parametrize("inclusive", [True, False])
def test_all_pairs_equals_the_kd_tree(box, inclusive):
    """The numpy all-pairs search (N <= BRUTE_FORCE_MAX) and scipy's k-d tree (above)
    find the same edges, with the strict or inclusive test, on the plane and the torus;
    some pairs sit exactly at the radius."""
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(3)
    pos = rng.uniform(0, 7.0, (900, 2))
    pos[1] = pos[0] + [0.5, 0.0]  # exactly at r = 0.5
    pos[3] = [6.9, 3.0]
    pos[2] = [0.2, 3.0]  # 0.3 apart across the periodic boundary
    got = geometry._all_pairs(pos, 0.5, inclusive, box)
    tree = cKDTree(np.mod(pos, box), boxsize=box) if box is not None else cKDTree(pos)
    want = {tuple(p) for p in tree.query_pairs(0.5 - (0 if inclusive else 1e-12))}
    assert {tuple(p) for p in got} == want
    assert ((0, 1) in want) == inclusive
    assert ((2, 3) in want) == (box is not None)
