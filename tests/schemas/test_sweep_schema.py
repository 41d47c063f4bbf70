"""The sweep file: expansion (product x zip x replicas, seeds) and every refusal. No engine."""

import copy
import json
import math
from pathlib import Path

import pytest

from flocklab.schemas import Scenario, get_preset
from flocklab.schemas.paths import PathError, merge, parse_assignment, set_path
from flocklab.schemas.sweep import MAX_RUNS, Sweep, SweepError, load_sweep, sweep_problems
from flocklab.schemas.sweep_presets import SWEEP_PRESETS, get_sweep_preset

BASE = {
    "model": {"kind": "vicsek", "rule": "vicsek", "v0": 0.03, "eta": 0.5},
    "space": {"kind": "periodic", "L": 5.0},
    "neighbours": {"radius": 1.0},
    "initial": {"kind": "random", "N": 100},
    "time": {"steps": 50},
    "seed": 11,
}


def sweep(**kw):
    return {"name": "s", "base": copy.deepcopy(BASE), **kw}


def locs(data):
    return [e.loc for e in sweep_problems(data)]


def test_product_times_zip_times_replicas_in_point_major_order():
    s = load_sweep(sweep(
        axes=[{"path": "model.eta", "values": [0.5, 1.0, 1.5]},
              {"zip": [{"path": "initial.N", "values": [100, 400]},
                       {"path": "space.L", "values": [5.0, 10.0]}]}],
        replicas=4))
    runs = s.expand()
    assert (s.n_points, s.n_runs, len(runs)) == (6, 24, 24)
    assert [r.index for r in runs] == list(range(24))
    # The last axis varies fastest; a zip entry moves its paths together.
    assert [(r.values["model.eta"], r.values["initial.N"], r.values["space.L"])
            for r in runs[::4]] == [(0.5, 100, 5.0), (0.5, 400, 10.0), (1.0, 100, 5.0),
                                    (1.0, 400, 10.0), (1.5, 100, 5.0), (1.5, 400, 10.0)]
    for r in runs:
        assert r.point == r.index // 4 and r.replica == r.index % 4
        assert r.scenario.model.eta == r.values["model.eta"]
        assert r.scenario.initial.N == r.values["initial.N"]
        assert r.scenario.space.L == r.values["space.L"]
        assert isinstance(r.scenario, Scenario) and r.scenario.time.steps == 50
    assert s.total_agent_steps == 3 * 4 * (100 + 400) * 50


@pytest.mark.parametrize("keep,own,expected", [
    ("table", None, ["polarization", "heading_spread"]),  # only what the tables read
    ("summaries", None, None),  # the summaries keep every observable's final value
    ("table", ["degree_mean"], ["degree_mean"]),  # the base's own list stands
])
def test_runs_compute_only_what_the_sweep_keeps(keep, own, expected):
    base = copy.deepcopy(BASE)
    base["recording"] = {"observables": own}
    s = load_sweep({"name": "s", "base": base, "keep": keep, "replicas": 2,
                    "measure": {"va": {"observable": "polarization", "reduce": "mean"}},
                    "series": ["heading_spread", "polarization"]})
    assert all(r.scenario.recording.observables == expected for r in s.expand())


def test_seed_rule_is_base_seed_plus_replica_and_seeds_list_replaces_it():
    runs = load_sweep(sweep(axes=[{"path": "model.eta", "values": [1, 2]}],
                            replicas=3)).expand()
    assert [r.seed for r in runs] == [11, 12, 13, 11, 12, 13]
    assert all(r.scenario.seed == r.seed for r in runs)
    runs = load_sweep(sweep(axes=[{"path": "model.eta", "values": [1, 2]}], replicas=2,
                            seeds=[7, 100, 5])).expand()
    assert [r.seed for r in runs] == [7, 100, 7, 100]
    assert "(root)" in locs(sweep(replicas=4, seeds=[1, 2]))  # fewer seeds than replicas


def test_replicas_per_grid_point_through_a_zip():
    s = load_sweep(sweep(axes=[{"zip": [{"path": "initial.N", "values": [100, 400]},
                                        {"path": "replicas", "values": [3, 1]}]}]))
    runs = s.expand()
    assert s.n_runs == 4 and [(r.point, r.replica, r.seed) for r in runs] == [
        (0, 0, 11), (0, 1, 12), (0, 2, 13), (1, 0, 11)]
    assert "replicas" not in runs[0].values  # not a scenario field, not a column
    one = load_sweep(sweep(axes=[{"zip": [{"path": "initial.N", "values": [100]},
                                          {"path": "replicas", "values": [3]}]}]))
    assert one.n_runs == len(one.expand()) == 3
    assert locs(sweep(replicas=2, axes=[{"path": "replicas", "values": [3]}])) == ["(root)"]
    assert "axes" in " ".join(
        e.msg for e in sweep_problems(sweep(axes=[{"path": "replicas", "values": [0]}])))


def test_preset_base_with_overrides():
    s = load_sweep({"name": "p", "preset": "vicsek-1995",
                    "overrides": {"time": {"steps": 20}, "model": {"eta": 1.0}},
                    "axes": [{"path": "initial.N", "values": [10, 20]}]})
    runs = s.expand()
    preset = get_preset("vicsek-1995")
    assert [r.scenario.initial.N for r in runs] == [10, 20]
    for r in runs:
        assert r.scenario.time.steps == 20 and r.scenario.model.eta == 1.0
        assert r.scenario.space == preset.space and r.seed == preset.seed
    bad = {"name": "p", "preset": "vicsek-1995", "overrides": {"model": {"eta": -1}}}
    assert locs(bad) == ["overrides.model.eta"]
    assert locs({"name": "p", "preset": "nope"}) == ["preset"]
    assert locs({"name": "p", "base": BASE, "preset": "vicsek-1995"}) == ["(root)"]


def test_unknown_path_names_the_axis_and_the_fields_there_are():
    errors = sweep_problems(sweep(axes=[{"path": "model.eta", "values": [1]},
                                        {"zip": [{"path": "initial.N", "values": [5]},
                                                 {"path": "space.Lx", "values": [5.0]}]}]))
    assert [e.loc for e in errors] == ["axes.1.zip.1.path"]
    assert "unknown field 'Lx'" in errors[0].msg and "L" in errors[0].msg
    assert locs(sweep(axes=[{"path": "initial.region.low", "values": [[0, 0]]}])) == [
        "axes.0.path"]  # the region is null in the base
    assert locs(sweep(axes=[{"path": "model..eta", "values": [1]}])) == ["axes.0.path"]
    assert locs(sweep(axes=[{"path": "seed", "values": [1]}])) == ["axes.0.path"]


def test_invalid_value_names_the_run_and_the_field():
    errors = sweep_problems(sweep(axes=[{"path": "model.eta", "values": [0.5, -1.0]},
                                        {"path": "initial.N", "values": [100, 0]}],
                                  replicas=2))
    got = {(e.loc, e.msg.split(" (")[1]) for e in errors}
    assert got == {
        ("runs[2].initial.N", "runs[2..3] at model.eta=0.5, initial.N=0)"),
        ("runs[4].model.eta", "runs[4..5] at model.eta=-1.0, initial.N=100)"),
        ("runs[6].model.eta", "runs[6..7] at model.eta=-1.0, initial.N=0)"),
        ("runs[6].initial.N", "runs[6..7] at model.eta=-1.0, initial.N=0)"),
    }
    with pytest.raises(SweepError) as exc:
        Sweep.model_validate(sweep(axes=[{"path": "model.eta", "values": [-1.0]}])).expand()
    assert exc.value.errors[0].loc == "runs[0].model.eta"
    # A cross-block check of the scenario: rule laplacian without g at one grid point.
    assert locs(sweep(axes=[{"path": "model.rule", "values": ["vicsek", "laplacian"]}])
                ) == ["runs[1].model"]


def test_structural_errors():
    assert locs(sweep(axes=[{"path": "model.eta", "values": []}])) == ["axes.0.values"]
    # Reported together with an unknown path elsewhere in the file.
    assert sorted(locs(sweep(axes=[{"path": "model.eta", "values": []},
                                   {"zip": [{"path": "model.v00", "values": [1]}]}],
                             replicas=0))) == ["axes.0.values", "axes.1.zip.0.path", "replicas"]
    unequal = sweep(axes=[{"zip": [{"path": "initial.N", "values": [1, 2]},
                                   {"path": "space.L", "values": [5.0]}]}])
    errors = sweep_problems(unequal)
    assert [e.loc for e in errors] == ["axes.0"]
    assert "initial.N has 2, space.L has 1" in errors[0].msg
    assert locs(sweep(axes=[{"path": "model.eta", "values": [1]},
                            {"path": "model.eta", "values": [2]}])) == ["(root)"]
    assert locs(sweep(axes=[{"path": "model", "values": [{}]},
                            {"path": "model.eta", "values": [2]}])) == ["(root)"]  # overlap
    assert locs(sweep(axes=[{"path": "model.eta", "values": [1], "x": 1}])) == ["axes.0.x"]
    assert locs(sweep(replicas=True)) == ["replicas"]
    assert locs(sweep(keep="everything")) == ["keep"]
    assert locs(sweep(measure={"run": {"observable": "polarization", "reduce": "mean"}})) == [
        "measure"]
    assert locs(sweep(measure={"va": {"observable": "polarization", "reduce": "median"}})) == [
        "measure.va.reduce"]
    assert locs(sweep(measure={"va": {"observable": "polarization", "reduce": "mean",
                                      "from_step": 40, "to_step": 10}})) == ["measure.va"]
    errors = sweep_problems(sweep(measure={"va": {"observable": "polarization",
                                                  "reduce": "mean", "from_step": 51}}))
    assert [e.loc for e in errors] == ["measure.va.from_step"]
    assert "time.steps = 50" in errors[0].msg


def test_too_many_runs_refused_before_expansion():
    big = sweep(axes=[{"path": "model.eta", "values": [0.1] * 1000},
                      {"path": "initial.N", "values": list(range(1, 1001))}])
    errors = sweep_problems(big)
    assert len(errors) == 1 and str(MAX_RUNS) in errors[0].msg
    assert str(MAX_RUNS) in sweep_problems(sweep(replicas=MAX_RUNS, axes=[
        {"path": "model.eta", "values": [1, 2]}]))[0].msg


def test_path_helper_shared_by_set_and_axes():
    doc = {"model": {"eta": 1.0}, "initial": {"region": None}, "xs": [1, 2]}
    assert set_path(doc, "model.eta", 3) == {"model": {"eta": 3}, "initial": {"region": None},
                                             "xs": [1, 2]}
    assert doc["model"]["eta"] == 1.0  # the original is untouched
    assert set_path(doc, "xs.1", 9)["xs"] == [1, 9]
    for bad in ("model.etaa", "model.eta.x", "initial.region.low", "xs.5", "", "a..b"):
        with pytest.raises(PathError):
            set_path(doc, bad, 0)
    assert parse_assignment("model.eta=3") == ("model.eta", 3)
    assert parse_assignment("model.rule=average") == ("model.rule", "average")
    assert parse_assignment('initial.region={"kind": "disc", "radius": 2}')[1]["radius"] == 2
    assert parse_assignment("neighbours.inclusive=false") == ("neighbours.inclusive", False)
    with pytest.raises(PathError):
        parse_assignment("model.eta")
    # Switching a union member replaces the object whole.
    assert merge({"space": {"kind": "periodic", "L": 5}}, {"space": {"kind": "plane"}}) == {
        "space": {"kind": "plane"}}


def test_vicsek_fig2_presets_state_the_full_protocol():
    a = get_sweep_preset("vicsek-1995-fig2a")
    runs = a.expand()
    assert sorted({r.values["model.eta"] for r in runs}) == [0.5 * k for k in range(1, 11)]
    by_n = {}
    for r in runs:
        sc = r.scenario
        assert sc.n_agents / sc.space.L ** 2 == pytest.approx(4.0)
        assert sc.model.v0 == 0.03 and sc.neighbours.radius == 1.0 and sc.inclusive
        by_n.setdefault(sc.n_agents, set()).add((r.replica, sc.time.steps))
    assert {n: (len(v), {s for _, s in v}) for n, v in by_n.items()} == {
        100: (8, {6000}), 400: (4, {6000}), 4000: (2, {8000})}
    assert a.n_runs == 10 * (8 + 4 + 2)
    assert a.measure["va"].from_step == 2000
    b = get_sweep_preset("vicsek-1995-fig2b")
    for r in b.expand():
        assert r.scenario.space.L == 20.0 and r.scenario.model.eta == 2.0
    assert sorted(SWEEP_PRESETS) == ["vicsek-1995-fig2a", "vicsek-1995-fig2b", "vicsek-fss"]
    assert math.isclose(b.n_runs, 40)


def test_example_sweep_file_is_issue_14s_benchmark():
    s = load_sweep(json.loads((Path(__file__).resolve().parents[2] / "examples" /
                               "sweep-fig2a-reduced.json").read_text()))
    assert (s.n_points, s.n_runs) == (20, 80)
    assert s.total_agent_steps == 10 * 4 * (100 + 400) * 3000


def test_sweep_json_schema_is_strict():
    schema = Sweep.model_json_schema()
    assert schema["additionalProperties"] is False
    assert {"axes", "base", "preset", "replicas", "seeds", "measure", "series", "keep"} <= set(
        schema["properties"])
