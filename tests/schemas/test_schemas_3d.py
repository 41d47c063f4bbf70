"""space.dimension: 3D scenarios validate, and every mismatch is a field error."""

import copy
import json
import subprocess
import sys

import pytest
from pydantic import ValidationError

from flocklab.schemas import MODELS, Scenario, field_errors

BASE = {
    "model": {"kind": "vicsek", "eta": 0.5},
    "space": {"kind": "periodic", "L": 5.0, "dimension": 3},
    "neighbours": {"radius": 1.0},
    "initial": {"kind": "random", "N": 100},
    "time": {"steps": 3},
}


def errors(change) -> list[tuple[str, str]]:
    doc = copy.deepcopy(BASE)
    change(doc)
    with pytest.raises(ValidationError) as exc:
        Scenario.model_validate(doc)
    return [(f.loc, f.msg) for f in field_errors(exc.value)]


def test_dimension_defaults_to_two():
    doc = copy.deepcopy(BASE)
    del doc["space"]["dimension"]
    assert Scenario.model_validate(doc).dimension == 2
    assert Scenario.model_validate(BASE).dimension == 3


@pytest.mark.parametrize("region", [
    {"kind": "box", "low": [0, 0, 0], "high": [1, 2, 3]},
    {"kind": "ball", "center": [2, 2, 2], "radius": 1.0},
    {"kind": "lattice", "low": [0, 0, 0], "spacing": 0.5},
])
def test_three_dimensional_regions(region):
    doc = copy.deepcopy(BASE)
    doc["initial"]["region"] = region
    assert Scenario.model_validate(doc).initial.region.dimension == 3


def test_explicit_state_with_three_columns():
    doc = copy.deepcopy(BASE)
    doc["space"] = {"kind": "plane", "dimension": 3}
    doc["initial"] = {"kind": "explicit", "positions": [[0, 0, 0], [1, 1, 1]],
                      "velocities": [[1, 0, 0], [0, 0, 1]]}
    assert Scenario.model_validate(doc).initial.N == 2


@pytest.mark.parametrize("rule", ["average", "laplacian", "leader"])
def test_angle_rules_refused_in_3d(rule):
    (loc, msg), = errors(lambda d: d["model"].update(rule=rule, g=1000.0 if rule == "laplacian"
                                                     else None))
    assert loc == "model" and f"rule {rule!r}" in msg and "2D only" in msg


def test_two_dimensional_only_model_refused_by_field(monkeypatch):
    # Every family runs in 3D now (formation was the last); a family declaring only
    # dimension 2 is still refused by the scenario with the field named.
    monkeypatch.setattr(MODELS["formation"], "dimensions", (2,))
    doc = copy.deepcopy(BASE)
    doc["space"] = {"kind": "plane", "dimension": 3}
    doc["initial"] = {"kind": "explicit", "positions": [[0, 0, 0], [30, 0, 0]]}
    doc["model"] = {"kind": "formation", "design": "F2",
                    "path": {"kind": "straight", "target": [1, 1, 1], "speed": 1.0}}
    with pytest.raises(ValidationError) as exc:
        Scenario.model_validate(doc)
    (err,) = field_errors(exc.value)
    assert err.loc == "space.dimension" and "runs in dimension 2, not 3" in err.msg


@pytest.mark.parametrize("change,loc,words", [
    (lambda d: d["initial"].update(region={"kind": "box", "low": [0, 0], "high": [1, 1]}),
     "space.dimension", "is 2D"),
    (lambda d: d["initial"].update(region={"kind": "disc", "radius": 1.0}),
     "space.dimension", "is 2D"),
    (lambda d: d["initial"].update(region={"kind": "box", "low": [0, 0, 0], "high": [1, 1]}),
     "initial.region", "low has 3 coordinates, high 2"),
    (lambda d: d["initial"].update(region={"kind": "box", "low": [0, 0, 0],
                                           "high": [1, 1, 6]}),
     "(root)", "[0, L]^3"),
    (lambda d: d.update(initial={"kind": "explicit", "positions": [[0, 0], [1, 1]]}),
     "space.dimension", "have 2 coordinates"),
    (lambda d: d.update(initial={"kind": "explicit", "positions": [[0, 0, 0], [1, 1]]}),
     "initial.positions", "positions[1] has 2 coordinates"),
    (lambda d: d.update(initial={"kind": "explicit", "positions": [[0, 0, 0]],
                                 "headings": [0.0]}),
     "initial", "give velocities in 3D"),
    (lambda d: d["initial"].update(heading_range=[0, 1]), "space.dimension", "sphere"),
    (lambda d: d["space"].update(dimension=4), "space.dimension", "2 or 3"),
])
def test_mismatches_are_field_errors(change, loc, words):
    (got_loc, msg), = errors(change)
    assert got_loc == loc and words in msg


def test_models_command_shows_dimensions():
    out = subprocess.run([sys.executable, "-m", "flocklab", "models"], check=True,
                         capture_output=True, text=True).stdout
    assert "dimensions: 2, 3 (3D for rule vicsek only" in out
    js = json.loads(subprocess.run([sys.executable, "-m", "flocklab", "models", "--json"],
                                   check=True, capture_output=True, text=True).stdout)
    dims = {m["kind"]: m["dimensions"] for m in js if "dimensions" in m}
    assert dims["vicsek"] == [2, 3]
