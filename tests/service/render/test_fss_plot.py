"""The finite-size-scaling preset, shrunk (two eta, two sizes, 300 steps), run for real:
its table pools the replicas' moments (checked against runs.csv by numpy), and its
picture draws G(eta) and chi(eta) per L in the papers' symbols."""

from __future__ import annotations

import csv
import json
import subprocess
import sys

import numpy as np
import pytest

from flocklab.schemas.sweep import SweepError, load_sweep
from flocklab.schemas.sweep_presets import SWEEP_PRESETS, get_sweep_preset
from flocklab.service.render.figure import new_figure
from flocklab.service.render.plots import draw_sweep
from flocklab.service.render.run_data import load_sweep as load_sweep_dir
from flocklab.service.sweeps import run_sweep
from tests.service.render.conftest import assert_picture, read_image


def _rows(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def test_the_preset_validates_and_is_sized_for_minutes():
    sweep = get_sweep_preset("vicsek-fss")
    assert sweep.n_points == 33 and sweep.n_runs == 11 * (8 + 4 + 4)
    assert sweep.total_agent_steps == pytest.approx(6.2e8, rel=0.01)
    runs = sweep.expand()
    assert {r.scenario.n_agents / r.scenario.space.L ** 2 for r in runs} == {2.0}


@pytest.mark.slow
def test_shrunken_fss_preset_table_and_picture(tmp_path, taichi_cpu):
    doc = SWEEP_PRESETS["vicsek-fss"].build()
    doc["axes"][0]["values"] = [2.8, 4.0]
    zipped = doc["axes"][1]["zip"]
    for member, values in zip(zipped, ([4, 8], [32, 128], [3, 2]), strict=True):
        member["values"] = values
    doc["base"]["time"]["steps"] = 300
    for m in doc["measure"].values():
        m["from_step"] = 100
    out = tmp_path / "fss"
    assert run_sweep(load_sweep(doc), out).status == "completed"

    runs, table = _rows(out / "runs.csv"), _rows(out / "table.csv")
    for row in table:
        mine = [r for r in runs if r["point"] == row["point"]]
        n = int(row["initial.N"])
        m2 = np.mean([float(r["G_m2"]) for r in mine])
        m4 = np.mean([float(r["G_m4"]) for r in mine])
        assert float(row["G_mean"]) == pytest.approx(1 - m4 / (3 * m2 ** 2), rel=1e-12)
        m1 = np.mean([float(r["chi_m1"]) for r in mine])
        chi = n * (np.mean([float(r["chi_m2"]) for r in mine]) - m1 ** 2)
        assert float(row["chi_mean"]) == pytest.approx(chi, rel=1e-12)
        assert int(row["G_count"]) == len(mine)
        # the run's own G and the moments measure agree on the same series
        for r in mine:
            assert float(r["G_m2"]) == pytest.approx(float(r["phi_m2"]), rel=1e-12)
            g = 1 - float(r["phi_m4"]) / (3 * float(r["phi_m2"]) ** 2)
            assert float(r["G"]) == pytest.approx(g, rel=1e-12)
    summary = json.loads((out / "runs" / "0" / "summary.json").read_text())
    assert summary["measures"]["G"] == pytest.approx(float(runs[0]["G"]), rel=1e-15)

    sweep = load_sweep_dir(out)
    fig = new_figure(900, 800)
    assert draw_sweep(fig, sweep, ["G", "chi"], 900, 800) == ["G", "chi"]
    top, bottom = fig.axes[:2]
    assert (top.get_ylabel(), bottom.get_ylabel(), bottom.get_xlabel()) == ("G", "χ", "η")
    assert {t.get_text() for t in top.get_legend().get_texts()} == {"L = 4", "L = 8"}

    png = tmp_path / "fss.png"
    r = subprocess.run([sys.executable, "-m", "flocklab", "render", str(out), "--plot",
                        "G,chi", "--out", str(png)], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0, r.stderr
    assert_picture(read_image(png), 900, 700, min_ink=0.01)


def test_labels_must_name_an_axis_or_a_quantity():
    doc = SWEEP_PRESETS["vicsek-fss"].build()
    doc["labels"]["model.etta"] = "η"
    with pytest.raises(SweepError, match=r"model\.etta"):
        load_sweep(doc)
