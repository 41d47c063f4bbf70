"""An Olfati-Saber run (Algorithm 3) through a real `flocklab serve` end to end: submitted,
run by a worker, its observables in the result, drawn by the render routes from the card
alone; a bad parameter is a 422 problem naming the field."""

from __future__ import annotations

import httpx
import pytest

from flocklab.schemas import get_preset
from tests.service.svc_helpers import assert_problem, submit, wait_for

PNG = b"\x89PNG\r\n\x1a\n"


def _scenario(**model) -> dict:
    sc = get_preset("olfati-saber-2006-alg3").model_dump(mode="json")
    sc["model"].update(model)
    sc["time"]["steps"] = 400
    sc["recording"] = {"every": 100, "arrays": ["position", "velocity"],
                       "observables_every": 50}
    return sc


@pytest.mark.slow
def test_an_olfati_saber_job_runs_and_is_drawn(http: httpx.Client):
    job = submit(http, {"scenario": _scenario()})
    done = wait_for(http, job["id"], timeout=120)
    assert done["status"] == "succeeded", done
    m = http.get(f"/v1/jobs/{job['id']}/metrics").json()
    assert m["summary"]["status"] == "completed" and m["summary"]["n_agents"] == 150
    obs = m["observables"]
    assert len(obs["deviation_energy"]) == len(obs["step"])
    assert min(obs["min_obstacle_distance"]) > 0
    assert 0 < obs["relative_connectivity"][-1] <= 1
    pytest.importorskip("matplotlib")
    for picture in ("snapshot.png", "observables.png"):
        r = http.get(f"/v1/jobs/{job['id']}/render/{picture}",
                     params={"width": 320, "height": 240}, timeout=120)
        assert r.status_code == 200, r.text
        assert r.headers["content-type"] == "image/png" and r.content.startswith(PNG)


def test_a_bad_olfati_saber_parameter_is_a_422_naming_it(http: httpx.Client):
    body = assert_problem(http.post("/v1/jobs", json={"scenario": _scenario(kappa=0.9)}),
                          422)
    assert "model.kappa" in str(body)
    body = assert_problem(http.post("/v1/jobs", json={"scenario": _scenario(leader=None)}),
                          422)
    assert "model.leader" in str(body)
