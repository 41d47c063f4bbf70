"""Every model family's card (schemas/catalog.py `ModelParams`): complete, consistent
with what the family reports, and exported as such by `describe_models()` (which GET
/v1/models serves, tests/service/app/test_catalog_route.py) and `flocklab models`."""

from __future__ import annotations

import json
import subprocess
import sys
from typing import get_args

import pytest

from flocklab.schemas import MODELS, PRESETS, describe_models, get_preset
from flocklab.schemas.catalog import Overlay

# The names `scene()` gives for each overlay drawn from the parameters alone.
SCENE = {"obstacles": {"obstacle_points", "disc_centres", "disc_radii", "destination"},
         "marked": {"marked", "marked_label"}}


@pytest.mark.parametrize("kind", list(MODELS))
def test_every_card_is_complete(kind):
    card = MODELS[kind]
    assert len(card.units) == 2
    assert all(u is None or (isinstance(u, str) and u.strip()) for u in card.units)
    assert card.default_plots, "no default plots"
    unknown = [n for n in card.default_plots if not card.reports(n)]
    assert not unknown, f"default plots the model does not report: {unknown}"
    assert card.details.startswith("docs/") and card.details.endswith(".md")
    assert set(card.overlays) <= set(get_args(Overlay))  # a family may draw none
    assert len(set(card.overlays)) == len(card.overlays)
    if card.constant_speed is not None:
        assert card.constant_speed in card.model_fields


@pytest.mark.parametrize("name", list(PRESETS))
def test_scene_names_what_the_overlays_draw(name):
    """Each preset's parameter-given overlay geometry: JSON-ready, and only under the
    names of the overlays its card draws."""
    model = get_preset(name).model
    scene = model.scene()
    json.dumps(scene)
    allowed = set().union(*(SCENE.get(o, set()) for o in type(model).overlays))
    assert set(scene) <= allowed, (set(scene) - allowed)
    if "obstacles" in type(model).overlays:
        assert set(scene) == SCENE["obstacles"]


def test_leader_rule_marks_agent_zero():
    assert get_preset("jlm-leader").model.scene()["marked"] == [0]
    assert get_preset("vicsek-1995").model.scene() == {}


def test_describe_models_exports_the_card():
    for m in describe_models():
        card = MODELS[m["kind"]]
        assert m["units"] == {"time": card.units[0], "length": card.units[1]}
        assert m["default_plots"] == list(card.default_plots)
        assert m["details"] == card.details
        assert m["overlays"] == list(card.overlays)
        assert m["constant_speed"] == card.constant_speed
        assert m["paper_inclusive"] == card.paper_inclusive


def test_flocklab_models_prints_the_card():
    """`flocklab models NAME` (a real subprocess): units, default plots and the details
    document from the card; --json adds the bibliography to the catalog entry."""
    proc = subprocess.run([sys.executable, "-m", "flocklab", "models", "flocking_obstacles"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    card = MODELS["flocking_obstacles"]
    assert "  units: time s, length m\n" in proc.stdout
    assert f"  plotted by default: {', '.join(card.default_plots)}\n" in proc.stdout
    assert f"  details: {card.details}\n" in proc.stdout
    proc = subprocess.run([sys.executable, "-m", "flocklab", "models", "vicsek", "--json"],
                          capture_output=True, text=True, timeout=120)
    one = json.loads(proc.stdout)
    entry = next(m for m in describe_models() if m["kind"] == "vicsek")
    assert one == {**json.loads(json.dumps(entry)), "references": "docs/REFERENCES.md"}
    assert "units: the model's own (dimensionless)" in subprocess.run(
        [sys.executable, "-m", "flocklab", "models", "vicsek"], capture_output=True,
        text=True, timeout=120).stdout
