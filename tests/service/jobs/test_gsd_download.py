"""GET /v1/jobs/{id}/trajectory.gsd on the real app: the job's GSD file (recording.format
gsd) with its digest and Range support, a 404 problem for a job without one, and the
clients' `download(path, format="gsd")`."""

from __future__ import annotations

import base64
import hashlib
from pathlib import Path

import gsd.hoomd
import numpy as np
import pytest

from tests.service.svc_helpers import assert_problem, scenario, submit, wait_for


def test_gsd_download_is_the_jobs_file(http, server, tmp_path):
    body = scenario(n=30, steps=10, every=5)
    body["recording"]["format"] = ["h5md", "gsd"]
    job = wait_for(http, submit(http, {"scenario": body})["id"])
    assert job["status"] == "succeeded", job
    r = http.get(f"/v1/jobs/{job['id']}/trajectory.gsd")
    assert r.status_code == 200 and r.headers["accept-ranges"] == "bytes"
    assert r.content == (server.data_dir / "results" / job["id"] / "trajectory.gsd"
                         ).read_bytes()
    assert job["checksums"]["trajectory.gsd"] == hashlib.sha256(r.content).hexdigest()
    digest = base64.b64encode(hashlib.sha256(r.content).digest()).decode()
    assert r.headers["repr-digest"] == f"sha-256=:{digest}:"
    assert f'filename="{job["id"]}.gsd"' in r.headers["content-disposition"]
    part = http.get(f"/v1/jobs/{job['id']}/trajectory.gsd", headers={"Range": "bytes=0-7"})
    assert part.status_code == 206 and part.content == r.content[:8]
    (tmp_path / "t.gsd").write_bytes(r.content)
    with gsd.hoomd.open(tmp_path / "t.gsd") as traj:
        assert [f.configuration.step for f in traj] == [0, 5, 10]
        assert traj[2].particles.N == 30
        assert np.all(np.abs(traj[2].particles.position[:, :2]) <= 2.5)  # L = 5


def test_job_without_gsd_is_404_problem(http):
    job = wait_for(http, submit(http, {"scenario": scenario(n=20, steps=5)})["id"])
    assert job["status"] == "succeeded" and "trajectory.gsd" not in job["checksums"]
    body = assert_problem(http.get(f"/v1/jobs/{job['id']}/trajectory.gsd"), 404)
    assert body["type"].endswith("no-trajectory") and "trajectory.gsd" in body["detail"]
    assert http.get(f"/v1/jobs/{job['id']}/trajectory.h5").status_code == 200


def test_clients_download_the_gsd_file(server, tmp_path):
    import asyncio

    from flocklab import clients

    body = scenario(n=25, steps=10, every=5)
    body["recording"]["format"] = "gsd"
    with clients.Client(server.url, transport=server.transport) as c:
        job = c.submit(body).wait(timeout=120)
        assert job.status == "succeeded"
        path = job.download(tmp_path / "sync.gsd", format="gsd")
        with pytest.raises(ValueError, match="format must be one of h5md, gsd"):
            job.download(tmp_path / "x", format="xyz")

    async def fetch() -> Path:
        async with clients.AsyncClient(server.url, transport=server.async_transport) as c:
            return await (await c.job(job.id)).download(tmp_path / "aio.gsd", format="gsd")

    other = asyncio.run(fetch())
    assert path.read_bytes() == other.read_bytes() == (
        server.data_dir / "results" / job.id / "trajectory.gsd").read_bytes()
    with gsd.hoomd.open(path) as traj:
        assert len(traj) == 3 and traj[0].particles.N == 25
