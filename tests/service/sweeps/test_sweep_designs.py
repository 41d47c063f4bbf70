"""A design sweep with a Morris analysis over HTTP on a real server: the sensitivity table
equals the local runner's (CSV and JSON), and a bad design is a problem naming the field."""

from __future__ import annotations

import json
from pathlib import Path

import httpx
import pytest

from tests.service.svc_helpers import assert_problem
from tests.service.sweeps.test_sweeps import http, submit, sweep_server, sweep_spec, wait_sweep  # noqa: F401


def design_spec() -> dict:
    spec = sweep_spec(steps=40)
    del spec["axes"], spec["series"]
    spec["replicas"] = 1
    spec["design"] = {"kind": "morris", "n": 3, "seed": 4,
                      "bounds": {"model.eta": [0.5, 5.0], "initial.N": [20, 40]},
                      "integer": ["initial.N"]}  # 3 x (2 + 1) = 9 runs
    spec["analysis"] = {"kind": "morris", "measure": "va"}
    return spec


@pytest.mark.slow
def test_sensitivity_table_over_http(http: httpx.Client, tmp_path: Path):  # noqa: F811
    from flocklab.schemas.sweep import Sweep
    from flocklab.service.sweeps.runner import run_sweep
    from flocklab.service.sweeps.tables import read_table

    spec = design_spec()
    created = submit(http, spec)
    assert created["runs_total"] == 9
    done = wait_sweep(http, created["id"])
    assert done["status"] == "succeeded", done
    assert "sensitivity.csv" in done["checksums"]
    local = tmp_path / "local"
    run_sweep(Sweep.model_validate_json(json.dumps(spec)), local)
    base = f"/v1/sweeps/{created['id']}"
    for name in ("table", "runs", "sensitivity"):
        r = http.get(f"{base}/{name}", params={"format": "csv"})
        assert r.status_code == 200 and r.content == (local / f"{name}.csv").read_bytes(), name
    body = http.get(f"{base}/sensitivity", params={"format": "json"}).json()
    assert body["columns"][:2] == ["parameter", "mu"]
    assert [row[0] for row in body["data"]] == ["model.eta", "initial.N"]
    assert body == {"sweep_id": created["id"], **read_table(local, "json", "sensitivity")}
    table = http.get(f"{base}/table", params={"format": "json"}).json()
    n_col = table["columns"].index("initial.N")
    assert all(type(row[n_col]) is int for row in table["data"])


def test_bad_design_is_a_problem(http: httpx.Client):  # noqa: F811
    spec = design_spec()
    spec["design"]["kind"] = "sobol"  # n = 3 is no power of 2, and analysis wants morris
    body = assert_problem(http.post("/v1/sweeps", json=spec), 422, "design")
    assert "power of 2" in json.dumps(body)
    spec = design_spec()
    spec["design"]["bounds"]["model.etta"] = [0, 1]
    assert_problem(http.post("/v1/sweeps", json=spec), 422, "design.bounds.model.etta")
