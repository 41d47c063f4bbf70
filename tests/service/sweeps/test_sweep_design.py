"""Sweep designs (lhs, sobol, halton, morris) and their sensitivity analysis with SALib:
the strata of a Latin hypercube, the known Sobol' indices of an additive function and of
Ishigami's, Morris effects of a linear function, seeds, refusals, and a real design sweep
end to end (runs.csv and table.csv columns, the same table twice, sensitivity.csv)."""

import csv
import math

import numpy as np
import pytest

from flocklab.schemas.sweep import SweepError, load_sweep
from flocklab.schemas.sweep_design import Analysis, Design
from flocklab.service.sweeps import run_sweep
from flocklab.service.sweeps.sensitivity import analyse


def _matrix(design, analysis=None):
    return np.array([list(p.values()) for p in design.points(analysis)], dtype=float)


def test_latin_hypercube_puts_one_point_in_each_stratum_of_each_axis():
    n = 41
    d = Design(kind="lhs", n=n, seed=5, bounds={"model.eta": (0.0, 5.0), "space.L": (1.0, 100.0),
                                              "initial.N": (10.0, 50.0)},
               log=["space.L"], integer=["initial.N"])
    x = _matrix(d)
    assert sorted(np.floor(x[:, 0] / 5.0 * n).astype(int)) == list(range(n))
    logs = (np.log(x[:, 1]) - math.log(1.0)) / (math.log(100.0) - math.log(1.0))
    assert sorted(np.floor(logs * n).astype(int)) == list(range(n))
    # 41 strata over the 41 integers 10 .. 50: every integer exactly once
    assert sorted(x[:, 2].astype(int)) == list(range(10, 51))
    assert all(type(p["initial.N"]) is int for p in d.points())


def test_seeds_give_the_same_design_and_other_seeds_another():
    kw = {"n": 16, "bounds": {"model.eta": (0.0, 5.0), "model.v0": (0.01, 1.0)}}
    for kind in ("lhs", "sobol", "halton", "morris"):
        a, b = Design(kind=kind, seed=1, **kw), Design(kind=kind, seed=1, **kw)
        assert a.points() == b.points()
        assert a.points() != Design(kind=kind, seed=2, **kw).points()
        assert len(a.points()) == a.n_points() == (16 * 3 if kind == "morris" else 16)


def test_sobol_indices_of_an_additive_function():
    """Y = sum_i a_i x_i, x_i uniform on [lo_i, hi_i]: V_i = a_i^2 (hi_i - lo_i)^2 / 12 and
    S1_i = ST_i = V_i / sum_j V_j (no interactions)."""
    bounds = {"p": (0.0, 1.0), "q": (-2.0, 2.0), "r": (0.0, 3.0)}
    a = np.array([4.0, 1.0, 0.5])
    d = Design(kind="sobol", n=2048, seed=9, bounds=bounds)
    y = _matrix(d, "sobol") @ a
    v = a ** 2 * np.array([(hi - lo) ** 2 for lo, hi in bounds.values()]) / 12
    exact = v / v.sum()
    res = analyse(d, Analysis(kind="sobol", measure="m", seed=1), y)
    for (s1, s1c, st, stc), e in zip(res, exact, strict=True):
        assert abs(s1 - e) < max(3 * s1c, 0.01) and abs(st - e) < max(3 * stc, 0.01)
        assert s1c < 0.05  # the intervals are tight enough for the check to bite
    assert exact.round(3).tolist() == [0.467, 0.467, 0.066]  # V = (16, 16, 2.25) / 12


@pytest.mark.slow
def test_sobol_indices_of_the_ishigami_function():
    """Ishigami & Homma (1990), a = 7, b = 0.1 on [-pi, pi]^3: S1 = (0.3139, 0.4424, 0),
    ST = (0.5576, 0.4424, 0.2437) — x3 acts only through its interaction with x1."""
    d = Design(kind="sobol", n=4096, seed=3, bounds={k: (-math.pi, math.pi) for k in "abc"})
    x = _matrix(d, "sobol")
    y = np.sin(x[:, 0]) + 7 * np.sin(x[:, 1]) ** 2 + 0.1 * x[:, 2] ** 4 * np.sin(x[:, 0])
    res = analyse(d, Analysis(kind="sobol", measure="m"), y)
    for (s1, s1c, st, stc), e1, et in zip(res, (0.3139, 0.4424, 0.0),
                                          (0.5576, 0.4424, 0.2437), strict=True):
        assert abs(s1 - e1) < 3 * s1c and abs(st - et) < 3 * stc


def test_morris_effects_of_a_linear_function():
    """Y = sum_i a_i x_i: every elementary effect per whole range is a_i (hi_i - lo_i), so
    mu = that, mu* = its magnitude and sigma = 0; a parameter without effect has mu* = 0."""
    bounds = {"p": (0.0, 2.0), "q": (1.0, 11.0), "r": (5.0, 6.0)}
    a = np.array([-3.0, 0.5, 0.0])
    d = Design(kind="morris", n=20, seed=4, levels=6, bounds=bounds)
    y = _matrix(d) @ a
    res = analyse(d, Analysis(kind="morris", measure="m"), y)
    for (mu, mu_star, sigma, _), ai, (lo, hi) in zip(res, a, bounds.values(), strict=True):
        assert mu == pytest.approx(ai * (hi - lo), abs=1e-9)
        assert mu_star == pytest.approx(abs(ai) * (hi - lo), abs=1e-9)
        assert sigma == pytest.approx(0.0, abs=1e-9)


BASE = {"name": "design", "preset": "vicsek-1995",
        "overrides": {"time": {"steps": 60}, "initial": {"N": 30}, "space": {"L": 3.0},
                      "recording": {"every": 0, "observables_every": 5}},
        "measure": {"va": {"observable": "polarization", "reduce": "mean", "from_step": 20}},
        "keep": "table"}


@pytest.mark.parametrize("bad, loc, text", [
    ({"design": {"kind": "sobol", "n": 6, "seed": 1, "bounds": {"model.eta": [0, 1]}}},
     "design", "power of 2"),
    ({"design": {"kind": "lhs", "n": 4, "seed": 1, "bounds": {"model.etta": [0, 1]}}},
     "design.bounds.model.etta", "unknown field 'etta'"),
    ({"design": {"kind": "lhs", "n": 4, "seed": 1, "bounds": {"model.eta": [1, 0]}}},
     "design.bounds", "low < high"),
    ({"design": {"kind": "lhs", "n": 4, "seed": 1, "bounds": {"model.eta": [0, 1]},
                 "log": ["model.eta"]}}, "design", "low bound > 0"),
    ({"design": {"kind": "lhs", "n": 4, "seed": 1, "bounds": {"model.eta": [0, 1]}},
      "analysis": {"kind": "sobol", "measure": "va"}}, "analysis", "kind 'sobol'"),
    ({"design": {"kind": "morris", "n": 4, "seed": 1, "bounds": {"model.eta": [0, 1]}},
      "analysis": {"kind": "morris", "measure": "vb"}}, "analysis", "'vb'"),
    ({"design": {"kind": "morris", "n": 60_000, "seed": 1, "bounds": {"model.eta": [0, 1]}}},
     "design", "more than the limit"),
    ({"design": {"kind": "lhs", "n": 4, "bounds": {"model.eta": [0, 1]}}}, "design.seed",
     "required"),
])
def test_refusals_name_the_field(bad, loc, text):
    with pytest.raises(SweepError) as err:
        load_sweep({**BASE, **bad})
    assert any(e.loc.startswith(loc) and text in e.msg for e in err.value.errors), \
        err.value.errors


def _rows(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def test_design_sweep_end_to_end(tmp_path, taichi_cpu):
    design = {"kind": "lhs", "n": 5, "seed": 2,
              "bounds": {"model.eta": [0.5, 5.0], "initial.N": [10, 40]},
              "integer": ["initial.N"]}
    doc = {**BASE, "design": design, "axes": [{"path": "neighbours.inclusive",
                                               "values": [True, False]}], "replicas": 2}
    sweep = load_sweep(doc)
    assert (sweep.n_points, sweep.n_runs) == (10, 20)
    for name in ("a", "b"):
        assert run_sweep(load_sweep(doc), tmp_path / name).status == "completed"
    table = (tmp_path / "a" / "table.csv").read_bytes()
    assert table == (tmp_path / "b" / "table.csv").read_bytes()  # same spec, same table
    rows = _rows(tmp_path / "a" / "table.csv")
    assert list(rows[0])[:4] == ["point", "neighbours.inclusive", "model.eta", "initial.N"]
    points = Design.model_validate(design).points()
    # the design varies fastest, under each value of the axis
    assert [(float(r["model.eta"]), int(r["initial.N"])) for r in rows] == 2 * [
        (p["model.eta"], p["initial.N"]) for p in points]
    runs = _rows(tmp_path / "a" / "runs.csv")
    assert [int(r["initial.N"]) for r in runs[::2]] == [r.scenario.n_agents
                                                      for r in sweep.expand()[::2]]


def test_morris_sweep_writes_sensitivity_csv(tmp_path, taichi_cpu):
    doc = {**BASE, "design": {"kind": "morris", "n": 3, "seed": 1,
                              "bounds": {"model.eta": [0.5, 5.0], "model.v0": [0.01, 0.3]},
                              "log": ["model.v0"]},
           "analysis": {"kind": "morris", "measure": "va", "seed": 2},
           "labels": {"model.eta": "η", "model.v0": "v₀", "va": "v_a"}}
    assert run_sweep(load_sweep(doc), tmp_path / "m").status == "completed"
    table = _rows(tmp_path / "m" / "table.csv")
    sens = _rows(tmp_path / "m" / "sensitivity.csv")
    assert [r["parameter"] for r in sens] == ["model.eta", "model.v0"]
    assert all(int(r["points"]) == 9 and r["points_missing"] == "0" for r in sens)
    # SALib on the table's column gives the file's numbers
    d = load_sweep(doc)
    y = np.array([float(r["va_mean"]) for r in table])
    res = analyse(d.design, d.analysis, y)
    assert [float(r["mu_star"]) for r in sens] == pytest.approx([v[1] for v in res],
                                                                rel=1e-12)
    # more noise lowers the order: eta's mean effect on v_a is negative
    assert float(sens[0]["mu"]) < 0

    # its pictures: the bars (the default for a folder with sensitivity.csv), the scatter
    from flocklab.service.render.figure import new_figure
    from flocklab.service.render.plots import draw_sweep
    from flocklab.service.render.run_data import load_sweep as load_sweep_dir

    data = load_sweep_dir(tmp_path / "m")
    fig = new_figure(800, 600)
    assert draw_sweep(fig, data, None, 800, 600) == ["sensitivity"]
    (ax,) = fig.axes
    assert [t.get_text() for t in ax.get_xticklabels()] == ["η", "v₀"]
    heights = sorted(round(b.get_height(), 9) for b in ax.patches)
    assert heights == sorted(round(float(r[c]), 9) for r in sens for c in ("mu_star", "sigma"))
    fig = new_figure(800, 600)
    assert draw_sweep(fig, data, ["va"], 800, 600) == ["va"]
    assert [a.get_xlabel() for a in fig.axes] == ["η", "v₀"]
    assert fig.axes[1].get_xscale() == "log"


def test_a_folder_from_before_designs_still_resumes(tmp_path, taichi_cpu):
    """sweep.json written without the fields added since (design, analysis, labels): the
    same sweep resumes there; one that sets a new field is another sweep."""
    import json

    from flocklab.service.sweeps import SweepFolderConflict

    doc = {**BASE, "axes": [{"path": "model.eta", "values": [1.0, 2.0]}]}
    out = tmp_path / "s"
    run_sweep(load_sweep(doc), out)
    meta = json.loads((out / "sweep.json").read_text())
    for k in ("design", "analysis", "labels"):
        del meta["sweep"][k]
    (out / "sweep.json").write_text(json.dumps(meta))
    again = run_sweep(load_sweep(doc), out)
    assert (again.status, again.runs_resumed) == ("completed", 2)
    with pytest.raises(SweepFolderConflict):
        run_sweep(load_sweep({**doc, "labels": {"model.eta": "η"}}), out)
