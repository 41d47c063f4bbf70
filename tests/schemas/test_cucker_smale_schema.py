"""Cucker–Smale's parameter block: bad values refused with a message naming the field, in
the schema and by `flocklab validate` (exit 2); the card in `flocklab models` says that a
cutoff changes the model."""

from __future__ import annotations

import json
import subprocess
import sys

import pydantic
import pytest

from flocklab.schemas import Scenario, get_preset


def body(**model) -> dict:
    sc = get_preset("cucker-smale-2007").model_dump(mode="json")
    sc["model"].update(model)
    return sc


@pytest.mark.parametrize(("change", "words"), [
    (lambda s: s["model"].update(beta=-0.1), "beta"),
    (lambda s: s["model"].update(K=0.0), "K"),
    (lambda s: s["model"].update(sigma=-1.0), "sigma"),
    (lambda s: s["model"].update(coupling=0.0), "coupling"),
    (lambda s: s["model"].update(normalization="median"), "normalization"),
    (lambda s: s["model"].update(cutoff=0.0), "cutoff"),
    (lambda s: s["model"].update(integrator="leapfrog"), "integrator"),
    (lambda s: s["initial"].update(N=20_000), "model.cutoff"),
    (lambda s: s["time"].update(dt=2.5), "time.dt"),
    (lambda s: (s["model"].update(normalization="sum"), s["time"].update(dt=0.05)),
     "time.dt"),
    (lambda s: s.update(neighbours={"radius": 1.0}), "model.cutoff"),
    (lambda s: (s.update(space={"kind": "periodic", "L": 20.0}),
                s["initial"]["region"].update(low=[1.0, 1.0], high=[9.0, 9.0])), "space.kind"),
], ids=["beta", "K", "sigma", "coupling", "normalization", "cutoff", "integrator",
        "all-to-all-too-large", "dt-mean", "dt-sum", "neighbours-block", "periodic"])
def test_bad_parameters_name_the_field(change, words):
    sc = body()
    change(sc)
    with pytest.raises(pydantic.ValidationError) as err:
        Scenario.model_validate(sc)
    assert words in str(err.value)


def test_a_cutoff_runs_any_n_and_the_card_is_served():
    sc = body(cutoff=1.0)
    sc["initial"]["N"] = 1_000_000
    Scenario.model_validate(sc)


def test_flocklab_validate_exits_2_naming_the_field(tmp_path):
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(body(beta=-1.0)))
    proc = subprocess.run([sys.executable, "-m", "flocklab", "validate", str(path)],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and "beta" in proc.stderr, proc.stderr
    assert "Traceback" not in proc.stderr


def test_flocklab_models_says_the_cutoff_changes_the_model():
    proc = subprocess.run([sys.executable, "-m", "flocklab", "models", "cucker_smale"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "CHANGES THE MODEL" in proc.stdout
    assert "docs/models/cucker_smale.md" in proc.stdout
