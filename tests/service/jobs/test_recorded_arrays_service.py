"""The derived per-agent arrays over HTTP: the shared real `flocklab serve` on 127.0.0.1
(tests/service/conftest.py) with its spawned worker runs a job recording `degree` at a
periodic radius beyond L/2, serves it from the trajectory route, and refuses `radius` for
Vicsek as problem+json."""

from __future__ import annotations

import io

import numpy as np

from tests.reference import degrees
from tests.service.svc_helpers import assert_problem, scenario, submit, wait_for


def test_a_job_serves_the_degrees_it_recorded(http):
    body = scenario(n=150, steps=10, every=5)  # L = 5
    body["neighbours"] = {"radius": 3.0}  # 0.6 L
    body["recording"]["arrays"] = ["position", "degree"]
    done = wait_for(http, submit(http, {"scenario": body})["id"])
    assert done["status"] == "succeeded", done
    r = http.get(f"/v1/jobs/{done['id']}/trajectory")
    z = np.load(io.BytesIO(r.content), allow_pickle=False)
    assert z["degree"].shape == (3, 150) and z["degree"].dtype == np.int32
    for k in range(3):
        np.testing.assert_array_equal(z["degree"][k], degrees(z["position"][k], 3.0, 5.0, True))
    j = http.get(f"/v1/jobs/{done['id']}/trajectory",
                 params={"format": "json", "arrays": "degree", "agents": "0,7"}).json()
    assert j["degree"] == z["degree"][:, [0, 7]].tolist()


def test_a_radius_for_vicsek_is_a_422_naming_the_field(http):
    """The cross-block check inside the request body is located at `scenario`, its
    message naming the field (as for the other cross-block checks there)."""
    body = scenario()
    body["recording"]["arrays"] = ["position", "radius"]
    problem = assert_problem(http.post("/v1/jobs", json={"scenario": body}), 422, "scenario")
    msgs = [e["msg"] for e in problem["errors"]]
    assert any(m.startswith("recording.arrays: model vicsek cannot record radius")
               for m in msgs), msgs
