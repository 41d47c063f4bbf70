"""Olfati-Saber's parameter block: bad values refused with a message naming the field, in
the schema and by `flocklab validate` (exit 2); the card in `flocklab models` lists the
algorithms and points at its page."""

from __future__ import annotations

import json
import subprocess
import sys

import pydantic
import pytest

from flocklab.schemas import Scenario, get_preset


def body(preset: str = "olfati-saber-2006-alg3", **model) -> dict:
    sc = get_preset(preset).model_dump(mode="json")
    sc["model"].update(model)
    return sc


def walls(**wall) -> list:
    return [{"kind": "wall", "point": [0.0, -45.0], "normal": [0.0, 1.0], **wall}]


@pytest.mark.parametrize(("change", "words"), [
    (lambda s: s["model"].update(algorithm=4), "algorithm"),
    (lambda s: s["model"].update(d=0.0), "d"),
    (lambda s: s["model"].update(kappa=1.0), "model.kappa"),
    (lambda s: s["model"].update(epsilon=1.5), "model.epsilon"),
    (lambda s: s["model"].update(h_alpha=1.0), "h_alpha"),
    (lambda s: s["model"].update(a=6.0), "model.a"),
    (lambda s: s["model"].update(c1_beta=-1.0), "c1_beta"),
    (lambda s: s["model"].update(leader=None), "model.leader"),
    (lambda s: s["model"].update(algorithm=1, obstacles=[]), "model.leader"),
    (lambda s: s["model"].update(algorithm=2), "model.obstacles"),
    (lambda s: s["model"].update(obstacles=walls(normal=[0.0, 0.0])), "normal"),
    (lambda s: s["model"].update(obstacles=walls(kind="plane")), "obstacles"),
    (lambda s: s["model"].update(obstacles=walls(point=[0.0, 1.0, 2.0])),
     "model.obstacles[0].point"),
    (lambda s: s["model"]["leader"].update(velocity=[1.0, 0.0, 0.0]),
     "model.leader.velocity"),
    (lambda s: s["model"].update(integrator="rk4"), "integrator"),
    (lambda s: s.update(neighbours={"radius": 1.0}), "neighbours"),
    (lambda s: (s.update(space={"kind": "periodic", "L": 200.0}),
                s["initial"]["region"].update(low=[1.0, 1.0], high=[90.0, 90.0])),
     "space.kind"),
], ids=["algorithm", "d", "kappa", "epsilon", "h", "a-above-b", "gain", "no-leader",
        "alg1-leader", "alg2-obstacles", "zero-normal", "obstacle-kind", "obstacle-dim",
        "leader-dim", "integrator", "neighbours-block", "periodic"])
def test_bad_parameters_name_the_field(change, words):
    sc = body()
    change(sc)
    with pytest.raises(pydantic.ValidationError) as err:
        Scenario.model_validate(sc)
    assert words in str(err.value)


def test_the_presets_and_a_large_n_validate():
    for name in ("olfati-saber-2006-alg1", "olfati-saber-2006-alg2"):
        sc = body(name)
        sc["initial"]["N"] = 1_000_000
        Scenario.model_validate(sc)


def test_flocklab_validate_exits_2_naming_the_field(tmp_path):
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(body(epsilon=-1.0)))
    proc = subprocess.run([sys.executable, "-m", "flocklab", "validate", str(path)],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and "epsilon" in proc.stderr, proc.stderr
    assert "Traceback" not in proc.stderr


def test_flocklab_models_shows_the_card():
    proc = subprocess.run([sys.executable, "-m", "flocklab", "models", "olfati_saber"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "docs/models/olfati_saber.md" in proc.stdout
    assert "relative_connectivity" in proc.stdout and "c1_gamma" in proc.stdout
