"""Couzin's parameter block: bad values refused with a message naming the field, in the
schema and by `flocklab validate` (exit 2); the card in `flocklab models` gives the
turning rate's unit and the docs page."""

from __future__ import annotations

import json
import subprocess
import sys

import pydantic
import pytest

from flocklab.schemas import PRESETS, Scenario, get_preset


def body(**model) -> dict:
    sc = get_preset("couzin-2002-torus").model_dump(mode="json")
    sc["model"].update(model)
    return sc


@pytest.mark.parametrize(("change", "words"), [
    (lambda s: s["model"].update(r_r=0.0), "r_r"),
    (lambda s: s["model"].update(dr_o=-1.0), "dr_o"),
    (lambda s: s["model"].update(dr_a=-0.5), "dr_a"),
    (lambda s: s["model"].update(field_of_view=400.0), "field_of_view"),
    (lambda s: s["model"].update(field_of_view=0.0), "field_of_view"),
    (lambda s: s["model"].update(turning_rate=0.0), "turning_rate"),
    (lambda s: s["model"].update(turning_rate=4000.0), "model.turning_rate"),
    (lambda s: s["model"].update(speed=-3.0), "speed"),
    (lambda s: s["model"].update(sigma=-0.1), "sigma"),
    (lambda s: s["model"].update(r_o=3.0), "r_o"),
    (lambda s: s.update(neighbours={"radius": 1.0}), "neighbours"),
    (lambda s: (s.update(space={"kind": "periodic", "L": 20.0, "dimension": 3}),
                s["initial"].update(region=None)), "space.kind"),
], ids=["r_r", "dr_o", "dr_a", "fov-high", "fov-zero", "turning-rate", "turn-per-step",
        "speed", "sigma", "unknown-field", "neighbours-block", "periodic"])
def test_bad_parameters_name_the_field(change, words):
    sc = body()
    change(sc)
    with pytest.raises(pydantic.ValidationError) as err:
        Scenario.model_validate(sc)
    assert words in str(err.value)


def test_the_presets_have_the_papers_parameters():
    """Table 1's values in every state preset; only Delta r_o differs, rising from swarm
    to highly parallel."""
    names = ["couzin-2002-swarm", "couzin-2002-torus", "couzin-2002-dynamic-parallel",
             "couzin-2002-parallel"]
    assert all(n in PRESETS for n in names)
    dr_o = []
    for n in names:
        sc = get_preset(n)
        p = sc.model
        assert (sc.n_agents, p.r_r, p.field_of_view, p.turning_rate, sc.time.dt, p.speed,
                p.sigma, p.dr_a, sc.dimension) == (100, 1.0, 270.0, 40.0, 0.1, 3.0, 0.05,
                                                   14.0, 3)
        dr_o.append(p.dr_o)
    assert dr_o == sorted(dr_o) and len(set(dr_o)) == 4


def test_flocklab_validate_exits_2_naming_the_field(tmp_path):
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(body(field_of_view=-10.0)))
    proc = subprocess.run([sys.executable, "-m", "flocklab", "validate", str(path)],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and "field_of_view" in proc.stderr, proc.stderr
    assert "Traceback" not in proc.stderr


def test_flocklab_models_lists_the_card():
    proc = subprocess.run([sys.executable, "-m", "flocklab", "models", "couzin"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "degrees per second" in proc.stdout
    assert "docs/models/couzin.md" in proc.stdout
