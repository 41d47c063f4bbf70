"""A Couzin run through the in-process service end to end: submitted, run by a worker, its
polarization and milling in the result, drawn by the render routes from the card alone;
a bad parameter is a 422 problem naming the field."""

from __future__ import annotations

import httpx
import pytest

from flocklab.schemas import get_preset
from tests.service.svc_helpers import assert_problem, submit, wait_for

PNG = b"\x89PNG\r\n\x1a\n"


def _scenario(**model) -> dict:
    sc = get_preset("couzin-2002-torus").model_dump(mode="json")
    sc["model"].update(model)
    sc["time"]["steps"] = 200
    sc["recording"]["every"] = 50
    return sc


@pytest.mark.slow
def test_a_couzin_job_runs_and_is_drawn(http: httpx.Client):
    job = submit(http, {"scenario": _scenario()})
    done = wait_for(http, job["id"], timeout=120)
    assert done["status"] == "succeeded", done
    m = http.get(f"/v1/jobs/{job['id']}/metrics").json()
    assert m["summary"]["status"] == "completed" and m["summary"]["n_agents"] == 100
    obs = m["observables"]
    assert len(obs["polarization"]) == len(obs["step"]) == len(obs["milling"])
    assert all(0.0 <= v <= 1.0 for v in obs["polarization"] + obs["milling"])
    pytest.importorskip("matplotlib")
    for picture in ("snapshot.png", "observables.png"):
        r = http.get(f"/v1/jobs/{job['id']}/render/{picture}",
                     params={"width": 320, "height": 240}, timeout=120)
        assert r.status_code == 200, r.text
        assert r.headers["content-type"] == "image/png" and r.content.startswith(PNG)


def test_a_bad_couzin_parameter_is_a_422_naming_it(http: httpx.Client):
    body = assert_problem(http.post("/v1/jobs", json={"scenario": _scenario(dr_o=-1.0)}),
                          422)
    assert "dr_o" in str(body)
    body = assert_problem(http.post("/v1/jobs", json={
        "scenario": _scenario(turning_rate=5000.0)}), 422)
    assert "model.turning_rate" in str(body)
