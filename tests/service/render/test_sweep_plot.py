"""The sweep plot, on a table written in the sweep folder format from real runs:
`table.csv` (axis columns, then <measure>_mean/_sd/_sem/_count) and `sweep.json`."""

from __future__ import annotations

import csv
import json
import subprocess
import sys

import numpy as np

from flocklab.schemas import Scenario
from flocklab.service.render.figure import new_figure
from flocklab.service.render.plots import draw_sweep
from flocklab.service.render.run_data import is_sweep_dir, load_sweep
from tests.service.render.conftest import assert_picture, read_image

ETAS, SIZES, REPLICAS = (0.5, 2.5, 5.0), (40, 80), 2


def _scenario(eta: float, n: int, seed: int) -> Scenario:
    return Scenario.model_validate({
        "model": {"kind": "vicsek", "rule": "vicsek", "v0": 0.03, "eta": eta},
        "space": {"kind": "periodic", "L": float(np.sqrt(n / 4))},
        "neighbours": {"radius": 1.0}, "initial": {"kind": "random", "N": n},
        "time": {"steps": 60, "dt": 1.0}, "recording": {"every": 0}, "seed": seed})


def test_sweep_plot_from_real_runs(tmp_path, taichi_cpu):
    from flocklab.service.execute import execute_to_dir

    folder = tmp_path / "sweep"
    folder.mkdir()
    rows = []
    for n in SIZES:
        for eta in ETAS:
            pol = [execute_to_dir(_scenario(eta, n, seed), tmp_path / f"r-{n}-{eta}-{seed}")
                   ["final"]["polarization"] for seed in range(REPLICAS)]
            sd = float(np.std(pol, ddof=1))
            rows.append([len(rows), eta, n, np.mean(pol), sd, sd / np.sqrt(REPLICAS),
                         REPLICAS])
    with (folder / "table.csv").open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["point", "model.eta", "initial.N", "polarization_mean", "polarization_sd",
                    "polarization_sem", "polarization_count"])
        w.writerows(rows)
    # as the sweep runner writes it: the spec under "sweep", the axis paths under "axes"
    (folder / "sweep.json").write_text(json.dumps({
        "sweep": {"name": "vicsek-eta", "axes": [{"path": "model.eta", "values": list(ETAS)},
                                                 {"path": "initial.N", "values": list(SIZES)}]},
        "axes": ["model.eta", "initial.N"], "measures": ["polarization"]}))
    assert is_sweep_dir(folder)
    sweep = load_sweep(folder)
    assert sweep.axes == ["model.eta", "initial.N"] and sweep.measures == ["polarization"]

    fig = new_figure(700, 500)
    assert draw_sweep(fig, sweep, None, 700, 500) == ["polarization"]
    ax = fig.axes[0]
    curves = [ln for ln in ax.get_lines() if ln.get_linestyle() not in ("None", "none")]
    assert len(curves) == len(SIZES)  # one curve per value of the second axis
    for ln in curves:
        assert list(ln.get_xdata()) == list(ETAS)
    assert {t.get_text() for t in ax.get_legend().get_texts()} == {
        f"initial.N = {n}" for n in SIZES}
    assert fig.get_suptitle() == "vicsek-eta: mean ± sem over replicas"

    out = tmp_path / "sweep.png"
    r = subprocess.run([sys.executable, "-m", "flocklab", "render", str(folder), "--out",
                        str(out)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["measures"] == ["polarization"]
    assert_picture(read_image(out), 900, 700, min_ink=0.01)
