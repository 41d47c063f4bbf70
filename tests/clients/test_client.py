"""The Python client against the real service (in-process, through `transport=`): sync
and async, results as numpy, typed errors, and an import that never pulls in Taichi or
FastAPI."""

from __future__ import annotations

import asyncio
import hashlib
import json
import subprocess
import sys
import time
import uuid

import h5py
import numpy as np
import pytest

from flocklab import clients
from flocklab.schemas import Problem, Scenario
from flocklab.schemas.status import JobView
from tests.clients.conftest import LONG, scenario


def test_importing_clients_loads_neither_taichi_nor_fastapi():
    code = ("import sys, flocklab; flocklab.Client; heavy = {'taichi', 'fastapi', "
            "'starlette', 'uvicorn', 'flocklab.kernels', 'flocklab.service', 'h5py'}; "
            "print(sorted({m for m in sys.modules if m.split('.')[0] in heavy "
            "or '.'.join(m.split('.')[:2]) in heavy}))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout
    assert out.strip() == "[]"


@pytest.mark.slow
def test_submit_wait_and_fetch_results(server, tmp_path, capsys):
    sc = Scenario.model_validate_json(json.dumps(scenario(n=80, steps=20, every=5)))
    with clients.Client(server.url, transport=server.transport) as c:
        job = c.submit(sc)
        assert job.status in ("queued", "running")
        assert job.wait(timeout=120, progress=True) is job
        assert job.status == "succeeded" and job.done and job.error is None
        assert "100%" in capsys.readouterr().err
        # Typed: the job is the schemas' JobView (datetimes, links), `data` its JSON.
        assert isinstance(job.state, JobView) and job.state.results == "available"
        assert job.state.finished_at >= job.state.created_at and job.state.finished_at.tzinfo
        assert job.state.steps_done == job.data["steps_done"] == 20

        m = job.metrics()
        assert m["summary"]["n_agents"] == 80
        pol = m["observables"]["polarization"]
        assert isinstance(pol, np.ndarray) and pol.dtype == float and len(pol) >= 20

        t = job.trajectory(start=1, stride=2, agents=slice(10, 30, 5))
        assert t["position"].shape == (2, 4, 2) and t["heading"].shape == (2, 4)
        np.testing.assert_array_equal(t["step"], [5, 15])
        np.testing.assert_array_equal(t["agents"], [10, 15, 20, 25])
        picked = job.trajectory(agents=[3, 1], arrays=["position"])
        assert set(picked) == {"step", "time", "agents", "position"}

        path = job.download(tmp_path / "t.h5")
        assert hashlib.sha256(path.read_bytes()).hexdigest() == job.data["checksums"][
            "trajectory.h5"]
        with h5py.File(path) as f:
            full = f["particles/swarm/position/value"][:]
        np.testing.assert_array_equal(t["position"], full[1::2, 10:30:5])
        np.testing.assert_array_equal(picked["position"], full[:, [3, 1]])


def test_presets_dicts_listing_and_catalog(server):
    with clients.Client(server.url, transport=server.transport) as c:
        a = c.submit(preset="vicsek-1995", overrides={"time": {"steps": 5}})
        b = c.submit(scenario(steps=3), timeout_seconds=60, idempotency_key=str(uuid.uuid4()))
        assert a.wait(120).status == b.wait(120).status == "succeeded"
        assert b.data["timeout_seconds"] == 60
        listed = [j.id for j in c.jobs(page_size=1)]
        assert listed.index(b.id) < listed.index(a.id)  # newest first, across pages
        assert all(j.status == "succeeded" for j in c.jobs(status="succeeded"))
        assert c.job(a.id).data["n_agents"] == 300
        assert "vicsek" in [m["kind"] for m in c.models()]
        assert "eta" in c.model_schema("vicsek")["properties"]
        assert "vicsek-1995" in [p["name"] for p in c.presets()]
        assert c.health()["status"] == "ok"
        with pytest.raises(ValueError):
            c.submit(scenario(), preset="vicsek-1995")


def test_typed_errors_carry_the_problem(server):
    with clients.Client(server.url, transport=server.transport) as c:
        bad = scenario()
        bad["time"]["dt"] = -1
        with pytest.raises(clients.UnprocessableEntity) as err:
            c.submit(bad)
        assert isinstance(err.value, clients.BadRequest) and err.value.status == 422
        assert [e["loc"] for e in err.value.errors] == ["scenario.time.dt"]
        assert err.value.problem["type"].endswith("validation-error")

        with pytest.raises(clients.NotFound):
            c.job(str(uuid.uuid4()))
        with pytest.raises(clients.UnprocessableEntity):
            c.job("not-a-uuid")
        with pytest.raises(clients.NotFound):
            c.model_schema("no-such-model")

        done = c.submit(scenario(steps=2)).wait(120)
        with pytest.raises(clients.Conflict) as err:
            done.cancel()
        assert err.value.problem["status_now"] == "succeeded"


def test_wait_timeout_then_cancel(server):
    with clients.Client(server.url, transport=server.transport) as c:
        job = c.submit(LONG)
        t0 = time.monotonic()
        with pytest.raises(clients.JobTimeout):
            job.wait(timeout=1.0, progress=False)
        assert time.monotonic() - t0 < 5
        job.cancel()
        assert job.wait(timeout=30).status == "cancelled"
        assert job.data["cancel_requested"] is True


@pytest.mark.slow
def test_auth_queue_limit_and_expiry_errors(strict_server):
    with clients.Client(strict_server.url, transport=strict_server.transport) as anonymous:
        with pytest.raises(clients.Unauthorized):
            anonymous.jobs().__next__()
        assert anonymous.health()["status"] == "ok"
    with clients.Client(strict_server.url, api_key="k3y",
                        transport=strict_server.transport) as c:
        done = c.submit(scenario(steps=2)).wait(120)
        assert done.status == "succeeded"
        deadline = time.monotonic() + 10
        while done.refresh().data["results"] != "expired":
            assert time.monotonic() < deadline
            time.sleep(0.2)
        with pytest.raises(clients.Gone):
            done.metrics()

        running = c.submit(LONG)
        while running.refresh(wait=1).status != "running":
            pass
        queued = c.submit(scenario(steps=2))
        with pytest.raises(clients.TooManyRequests) as err:
            c.submit(scenario(steps=2))
        assert err.value.retry_after is not None and err.value.retry_after >= 1
        running.cancel()
        assert queued.wait(120).status == "succeeded"


def test_async_client(server):
    async def main() -> None:
        async with clients.AsyncClient(server.url, transport=server.async_transport) as c:
            job = await c.submit(scenario(steps=10, every=5))
            await job.wait(timeout=120, progress=False)
            assert job.status == "succeeded"
            t = await job.trajectory(agents="0:8")
            assert t["position"].shape == (3, 8, 2)
            m = await job.metrics()
            assert m["summary"]["steps"] == 10
            ids = [j.id async for j in c.jobs(page_size=2)]
            assert job.id in ids
            long = await c.submit(LONG)
            await long.cancel()
            assert (await long.wait(timeout=30)).status == "cancelled"
            with pytest.raises(clients.NotFound):
                await c.job(str(uuid.uuid4()))
            assert [m["kind"] for m in await c.models()]

    asyncio.run(main())


@pytest.mark.slow
def test_a_failed_job_carries_its_problem_typed(server):
    # Two agents at one point: the pair force is infinite at the first step.
    body = {"model": {"kind": "flocking"}, "space": {"kind": "plane"},
            "neighbours": {"radius": 2.0},
            "initial": {"kind": "explicit", "positions": [[0, 0], [0, 0], [1, 0]]},
            "time": {"steps": 50, "dt": 0.01}, "recording": {"every": 1}}
    with clients.Client(server.url, transport=server.transport) as c:
        job = c.submit(body).wait(timeout=120)
    assert job.status == "failed"
    assert isinstance(job.error, Problem) and job.error.type.endswith("diverged")
    assert job.error.model_extra["step"] <= 2 and job.error.status >= 400

