"""The sweep runner on real runs (small N, few steps): tables, resume, keep levels."""

import csv
import json
import math

import numpy as np
import pytest

from flocklab.schemas.sweep import SweepError, load_sweep
from flocklab.schemas.sweep_presets import SWEEP_PRESETS
from flocklab.service.cli import main
from flocklab.service.sweeps import SweepFolderConflict, read_table, run_sweep
from flocklab.service.sweeps.journal import read_journal

OVERRIDES = {"time": {"steps": 40}, "initial": {"N": 20},
             "recording": {"every": 0, "observables_every": 5}}
MEASURES = {
    "va": {"observable": "polarization", "reduce": "mean", "from_step": 10},
    "va_std": {"observable": "polarization", "reduce": "std", "from_step": 10},
    "va_final": {"observable": "polarization", "reduce": "final"},
    "va_min": {"observable": "polarization", "reduce": "min", "to_step": 20},
    "spread_max": {"observable": "heading_spread", "reduce": "max", "from_step": 5,
                   "to_step": 35},
    "settle": {"observable": "heading_spread", "reduce": "converge_time", "tolerance": 3.0},
}


def small_sweep(**kw):
    doc = {"name": "small", "preset": "vicsek-1995", "overrides": OVERRIDES,
           "axes": [{"path": "model.eta", "values": [0.5, 3.0]},
                    {"zip": [{"path": "initial.N", "values": [20, 40]},
                             {"path": "space.L", "values": [4.0, 5.0]}]}],
           "replicas": 2, "measure": MEASURES, "series": ["polarization"]}
    return load_sweep({**doc, **kw})


def rows(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def num(cell):
    return float(cell) if cell else None


def by_hand(measure, obs):
    """The reductions written out again, from a run's observables.csv."""
    step, t, v = obs["step"], obs["time"], obs[measure["observable"]]
    w = (step >= measure.get("from_step", 0)) & (step <= measure.get("to_step", math.inf))
    v, t = v[w], t[w]
    red = measure["reduce"]
    if red == "converge_time":
        tol = measure["tolerance"]
        if not v[-1] < tol:
            return None
        above = np.nonzero(~(v < tol))[0]
        return float(t[0] if len(above) == 0 else t[above[-1] + 1])
    return float({"mean": np.mean, "std": np.std, "final": lambda a: a[-1], "min": np.min,
                  "max": np.max}[red](v))


def test_table_equals_a_hand_loop_over_flocklab_run(tmp_path, capsys, taichi_cpu):
    sweep = small_sweep()
    outcome = run_sweep(sweep, tmp_path / "sweep")
    assert (outcome.status, outcome.runs_done, outcome.runs_total) == ("completed", 8, 8)
    # The same runs by hand: `flocklab run` of the base preset with --set per run.
    per_run = {}
    for r in sweep.expand():
        out = tmp_path / f"hand{r.index}"
        sets = [f"{k}={json.dumps(v)}" for k, v in r.values.items()] + [
            "time.steps=40", "recording.every=0", "recording.observables_every=5",
            f"seed={r.seed}"]
        argv = ["run", "preset:vicsek-1995", "--out", str(out), "--quiet"]
        assert main([*argv, *(x for s in sets for x in ("--set", s))]) == 0
        obs = np.genfromtxt(out / "observables.csv", delimiter=",", names=True)
        per_run[r.index] = (r, {n: by_hand(m, obs) for n, m in MEASURES.items()}, obs)
    capsys.readouterr()
    runs = rows(tmp_path / "sweep" / "runs.csv")
    assert [int(x["run"]) for x in runs] == list(range(8))
    for x in runs:
        r, hand, _ = per_run[int(x["run"])]
        assert (x["status"], int(x["seed"]), float(x["model.eta"])) == (
            "completed", r.seed, r.values["model.eta"])
        for n in MEASURES:
            assert num(x[n]) == (None if hand[n] is None else
                                 pytest.approx(hand[n], rel=1e-12, abs=0))
    table = rows(tmp_path / "sweep" / "table.csv")
    assert len(table) == 4
    for p, row in enumerate(table):
        members = [v for v in per_run.values() if v[0].point == p]
        assert float(row["space.L"]) == members[0][0].values["space.L"]
        for n in MEASURES:
            x = np.array([h[n] for _, h, _ in members if h[n] is not None])
            assert int(row[f"{n}_count"]) == len(x)
            if len(x) == 0:
                assert row[f"{n}_mean"] == row[f"{n}_sd"] == ""
                continue
            assert num(row[f"{n}_mean"]) == pytest.approx(x.mean(), rel=1e-12)
            if len(x) == 2:
                sd = x.std(ddof=1)
                assert num(row[f"{n}_sd"]) == pytest.approx(sd, rel=1e-12, abs=1e-300)
                assert num(row[f"{n}_sem"]) == pytest.approx(sd / math.sqrt(2), rel=1e-12,
                                                             abs=1e-300)
    # The series: mean and sd over the replicas at each observation step.
    series = rows(tmp_path / "sweep" / "series.csv")
    first = [s for s in series if s["point"] == "0"]
    stack = np.array([o["polarization"] for r, _, o in per_run.values() if r.point == 0])
    assert [int(s["step"]) for s in first] == list(range(0, 41, 5))
    assert [float(s["polarization_mean"]) for s in first] == pytest.approx(stack.mean(0),
                                                                           rel=1e-12)
    assert [float(s["polarization_sd"]) for s in first] == pytest.approx(
        stack.std(0, ddof=1), rel=1e-12)
    # Typed JSON for the service, loadable as numpy without options.
    obj = read_table(tmp_path / "sweep", "json")
    assert obj["columns"][:4] == ["point", "model.eta", "initial.N", "space.L"]
    assert obj["data"][3][:4] == [3, 3.0, 40, 5.0]
    arr = np.genfromtxt(tmp_path / "sweep" / "table.csv", delimiter=",", names=True)
    assert arr.shape == (4,) and np.isfinite(arr["va_mean"]).all()
    try:
        import pandas
    except ImportError:
        return
    assert pandas.read_csv(tmp_path / "sweep" / "runs.csv").shape == (8, 8 + len(MEASURES))


def test_interrupted_sweep_resumes_without_redoing_finished_runs(tmp_path, taichi_cpu,
                                                                  monkeypatch):
    # One run per engine call, so a stop can land between runs (the engine batches the
    # runs it is given into one launch, and they all finish together).
    monkeypatch.setattr("flocklab.service.sweeps.executors.BATCH_RUNS", 1)
    sweep = small_sweep(measure={"va": MEASURES["va"]}, replicas=1)
    out = tmp_path / "resumed"
    seen = []
    first = run_sweep(sweep, out, on_progress=seen.append,
                      should_stop=lambda: bool(seen) and seen[-1].runs_done >= 2)
    assert (first.status, first.runs_done, first.runs_total) == ("cancelled", 2, 4)
    assert [x["status"] for x in rows(out / "runs.csv")] == ["completed"] * 2 + ["pending"] * 2
    kept = {i: (out / "runs" / str(i) / "summary.json").stat().st_mtime_ns for i in (0, 1)}
    assert not (out / "runs" / "2").exists()
    second = run_sweep(sweep, out)
    assert (second.status, second.runs_done, second.runs_resumed) == ("completed", 4, 2)
    assert {i: (out / "runs" / str(i) / "summary.json").stat().st_mtime_ns
            for i in (0, 1)} == kept
    lines = (out / "runs.jsonl").read_text().splitlines()
    assert sorted(json.loads(x)["run"] for x in lines) == [0, 1, 2, 3]  # none redone
    whole = run_sweep(sweep, tmp_path / "whole")
    assert whole.status == "completed"
    for name in ("table.csv", "runs.csv", "series.csv"):
        assert (out / name).read_bytes() == (tmp_path / "whole" / name).read_bytes()
    # A third run finds everything done; a torn journal line is ignored and redone.
    (out / "runs.jsonl").write_text("\n".join(lines[:3]) + "\n" + lines[3][:20])
    assert sorted(read_journal(out)) == sorted(json.loads(x)["run"] for x in lines[:3])
    again = run_sweep(sweep, out)
    assert (again.runs_done, again.runs_resumed) == (4, 3)
    assert (out / "table.csv").read_bytes() == (tmp_path / "whole" / "table.csv").read_bytes()


def test_keep_levels_and_folder_conflicts(tmp_path, taichi_cpu):
    small = {"axes": [{"path": "model.eta", "values": [1.0, 2.0]}], "replicas": 1,
             "measure": {"va": MEASURES["va"]}, "series": []}
    table_only = run_sweep(small_sweep(**small, keep="table"), tmp_path / "t")
    assert table_only.status == "completed" and not (tmp_path / "t" / "runs").exists()
    assert not (tmp_path / "t" / "series.csv").exists()
    run_sweep(small_sweep(**small, keep="all"), tmp_path / "a")
    for i in (0, 1):
        files = sorted(p.name for p in (tmp_path / "a" / "runs" / str(i)).iterdir())
        assert files == ["observables.csv", "scenario.json", "summary.json", "trajectory.h5"]
    # Same bits whichever engine entry ran them (run_batch, or execute_to_dir per run).
    assert [x["va"] for x in rows(tmp_path / "t" / "runs.csv")] == [
        x["va"] for x in rows(tmp_path / "a" / "runs.csv")]
    with pytest.raises(SweepFolderConflict, match="different sweep"):
        run_sweep(small_sweep(**small, keep="summaries"), tmp_path / "t")
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "notes.txt").write_text("mine")
    with pytest.raises(SweepFolderConflict, match="holds no sweep"):
        run_sweep(small_sweep(**small), tmp_path / "other")


def test_unknown_observable_fails_before_any_run(tmp_path, taichi_cpu):
    sweep = small_sweep(measure={"va": {"observable": "polarisation", "reduce": "mean"}})
    with pytest.raises(SweepError) as exc:
        run_sweep(sweep, tmp_path / "x")
    assert exc.value.errors[0].loc == "measure.va.observable"
    assert "polarization" in exc.value.errors[0].msg  # lists the ones there are
    assert not (tmp_path / "x").exists()  # so the corrected sweep is no "other sweep"


def test_a_diverged_run_is_recorded_and_left_out_of_the_table(tmp_path, taichi_cpu):
    base = {"model": {"kind": "vicsek", "v0": 0.03}, "space": {"kind": "plane"},
            "neighbours": {"radius": 1.0},
            "initial": {"kind": "random", "N": 30,
                        "region": {"kind": "box", "low": [0, 0], "high": [3, 3]}},
            "time": {"steps": 20}}
    sweep = load_sweep({"name": "blow-up", "base": base,
                        "axes": [{"path": "model.v0", "values": [0.03, 1e300]}],
                        "measure": {"va": {"observable": "polarization", "reduce": "mean"}}})
    outcome = run_sweep(sweep, tmp_path / "d")
    assert (outcome.status, outcome.runs_done, outcome.runs_failed) == ("completed", 1, 1)
    runs = rows(tmp_path / "d" / "runs.csv")
    assert [x["status"] for x in runs] == ["completed", "diverged"] and runs[1]["va"] == ""
    table = rows(tmp_path / "d" / "table.csv")
    assert [x["va_count"] for x in table] == ["1", "0"] and table[1]["va_mean"] == ""
    summary = json.loads((tmp_path / "d" / "runs" / "1" / "summary.json").read_text())
    assert summary["status"] == "diverged" and summary["sweep_run"]["values"] == {
        "model.v0": 1e300}


def test_shrunken_fig2a_preset(tmp_path, taichi_cpu):
    doc = SWEEP_PRESETS["vicsek-1995-fig2a"].build()
    doc["axes"][0]["values"] = [0.5, 5.0]
    sizes = [36, 64]
    doc["axes"][1]["zip"] = [
        {"path": "initial.N", "values": sizes},
        {"path": "space.L", "values": [math.sqrt(n / 4) for n in sizes]},
        {"path": "replicas", "values": [2, 1]},
        {"path": "time.steps", "values": [150, 150]},
    ]
    for m in doc["measure"].values():
        m["from_step"] = 50
    outcome = run_sweep(load_sweep(doc), tmp_path / "fig2a")
    assert (outcome.status, outcome.runs_total) == ("completed", 6)
    table = np.genfromtxt(tmp_path / "fig2a" / "table.csv", delimiter=",", names=True)
    assert list(table["initialN"]) == [36, 64, 36, 64]  # numpy drops the dot in names
    assert list(table["va_count"]) == [2, 1, 2, 1]
    low, high = table[table["modeleta"] == 0.5], table[table["modeleta"] == 5.0]
    assert (low["va_mean"] > high["va_mean"] + 0.2).all()  # ordered at low noise
    series = np.genfromtxt(tmp_path / "fig2a" / "series.csv", delimiter=",", names=True)
    assert len(series) == 4 * 16  # observations every 10 steps, 0..150
