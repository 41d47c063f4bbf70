"""The render routes on the real app (in-process; one check on a real `flocklab serve`):
pictures of finished jobs, drawn once in a child process and then served from the results
folder; the result routes' errors and auth; the viewer and offline Swagger UI; matplotlib
never loaded by the API process."""

from __future__ import annotations

import time
from pathlib import Path

import httpx
import numpy as np
import pytest

from flocklab import clients
from tests.service.svc_helpers import assert_problem, long_scenario, scenario, submit, wait_for

pytest.importorskip("matplotlib")
PNG = b"\x89PNG\r\n\x1a\n"


def _image(content: bytes) -> np.ndarray:
    import imageio.v3 as iio

    return iio.imread(content)


@pytest.fixture(scope="module")
def done_job(server) -> str:
    with server.client(timeout=30) as http:
        job = submit(http, scenario(n=60, steps=40, every=5))
        assert wait_for(http, job["id"])["status"] == "succeeded"
    return job["id"]


@pytest.mark.slow
def test_snapshot_is_drawn_once_then_served_from_the_results(server, http, done_job):
    path = f"/v1/jobs/{done_job}/render/snapshot.png"
    r = http.get(path, params={"width": 320, "height": 240, "frame": 3}, timeout=120)
    assert r.status_code == 200, r.text
    assert r.headers["content-type"] == "image/png" and r.content.startswith(PNG)
    img = _image(r.content)
    assert img.shape[:2] == (240, 320) and img[..., :3].std() > 10
    cached = list((server.data_dir / "results" / done_job / "render").glob("snapshot-*.png"))
    assert len(cached) == 1 and cached[0].read_bytes() == r.content
    t0 = time.perf_counter()
    again = http.get(path, params={"width": 320, "height": 240, "frame": 3})
    assert again.content == r.content and time.perf_counter() - t0 < 2.0
    other = http.get(path, params={"width": 200, "height": 200}, timeout=120)
    assert _image(other.content).shape[:2] == (200, 200)


@pytest.mark.slow
def test_observables_and_movie(http, done_job):
    r = http.get(f"/v1/jobs/{done_job}/render/observables.png",
                 params={"names": "polarization,components", "width": 500, "height": 400},
                 timeout=120)
    assert r.status_code == 200 and _image(r.content).shape[:2] == (400, 500)
    r = http.get(f"/v1/jobs/{done_job}/render/movie.mp4",
                 params={"width": 160, "height": 160, "fps": 5}, timeout=300)
    assert r.status_code == 200, r.text
    assert r.headers["content-type"] == "video/mp4" and r.content[4:8] == b"ftyp"


@pytest.fixture(scope="module")
def done_job_3d(server) -> str:
    """A finished 3D Vicsek job (the periodic cube)."""
    sc = scenario(n=80, steps=30, every=5)
    sc["space"]["dimension"] = 3
    with server.client(timeout=30) as http:
        job = submit(http, sc)
        assert wait_for(http, job["id"])["status"] == "succeeded"
    return job["id"]


@pytest.mark.slow
def test_a_3d_job_is_drawn(server, http, done_job_3d):
    """A 3D job's snapshot (every agent through the 3D camera), movie and the client's
    job.snapshot(), as for a 2D job."""
    base = f"/v1/jobs/{done_job_3d}/render"
    r = http.get(f"{base}/snapshot.png", params={"width": 300, "height": 260, "trails": 2},
                 timeout=120)
    assert r.status_code == 200, r.text
    img = _image(r.content)
    assert img.shape[:2] == (260, 300) and img[..., :3].std() > 10
    assert (img[..., :3] < 235).any(axis=2).mean() > 0.03
    r = http.get(f"{base}/movie.mp4", params={"width": 160, "height": 160, "fps": 5},
                 timeout=300)
    assert r.status_code == 200, r.text
    assert r.headers["content-type"] == "video/mp4" and r.content[4:8] == b"ftyp"
    with clients.Client(server.url, transport=server.transport) as c:
        content = c.job(done_job_3d).snapshot(width=200, height=200, field="density")
        assert _image(content).shape[:2] == (200, 200)


@pytest.mark.slow
def test_render_errors_are_problems(http, done_job, server):
    base = f"/v1/jobs/{done_job}/render"
    body = assert_problem(http.get(f"{base}/snapshot.png", params={"frame": 999},
                                   timeout=120), 422, "query.frame")
    assert "out of range" in body["detail"]
    assert_problem(http.get(f"{base}/snapshot.png", params={"width": 10}), 422, "query.width")
    assert_problem(http.get(f"{base}/snapshot.png", params={"frame": 1, "time": 2.0}), 422,
                   "query.time")
    assert_problem(http.get(f"{base}/observables.png", params={"names": "nope"},
                            timeout=120), 422, "query.names")
    assert_problem(http.get("/v1/jobs/00000000-0000-4000-8000-000000000000/render/"
                            "snapshot.png"), 404)
    assert_problem(http.get("/v1/jobs/not-a-uuid/render/snapshot.png"), 422)
    running = submit(http, long_scenario())
    try:
        assert_problem(http.get(f"/v1/jobs/{running['id']}/render/snapshot.png"), 409)
    finally:
        http.post(f"/v1/jobs/{running['id']}/cancel")
    no_frames = submit(http, scenario(n=30, steps=5, every=0))
    wait_for(http, no_frames["id"])
    assert_problem(http.get(f"/v1/jobs/{no_frames['id']}/render/snapshot.png", timeout=120),
                   404)


def test_results_deleted_while_drawing_answer_410(server, http):
    """The results folder removed while a movie is being drawn (expiry, or by hand): the
    route answers the result routes' 410, not a server error."""
    import shutil
    import threading

    job = submit(http, scenario(n=200, steps=100, every=1))
    assert wait_for(http, job["id"])["status"] == "succeeded"
    folder = server.data_dir / "results" / job["id"]
    answer: list[httpx.Response] = []
    ask = threading.Thread(target=lambda: answer.append(http.get(
        f"/v1/jobs/{job['id']}/render/movie.mp4", params={"width": 480, "height": 480},
        timeout=300)))
    ask.start()
    deadline = time.monotonic() + 60
    while not (folder / "render").is_dir():  # the draw has begun
        assert time.monotonic() < deadline
        time.sleep(0.01)
    while folder.exists():  # the worker may add its file while the tree is removed
        shutil.rmtree(folder, ignore_errors=True)
    ask.join(300)
    assert_problem(answer[0], 410)


@pytest.mark.slow
def test_client_snapshot(server, done_job, tmp_path):
    with clients.Client(server.url, transport=server.transport) as c:
        job = c.job(done_job)
        content = job.snapshot(width=256, height=256, field="arrows", trails=0)
        assert isinstance(content, bytes) and _image(content).shape[:2] == (256, 256)
        saved = job.snapshot(tmp_path / "s.png", width=256, height=256)
        assert saved == tmp_path / "s.png" and saved.read_bytes().startswith(PNG)
        with pytest.raises(clients.UnprocessableEntity) as exc:
            job.snapshot(frame=10_000)
        assert exc.value.errors[0]["loc"] == "query.frame"


@pytest.mark.slow
def test_render_routes_need_the_api_key(make_app):
    s = make_app({"FLOCKLAB_API_KEY": "s3cret"})
    key = {"X-API-Key": "s3cret"}
    with s.client(timeout=120) as http:
        job = submit(http, scenario(n=30, steps=10, every=5), headers=key)
        deadline = time.monotonic() + 60
        while http.get(f"/v1/jobs/{job['id']}", headers=key).json()["status"] != "succeeded":
            assert time.monotonic() < deadline
            time.sleep(0.2)
        path = f"/v1/jobs/{job['id']}/render/snapshot.png"
        assert_problem(http.get(path), 401)
        assert http.get(path, headers=key).content.startswith(PNG)
        # the viewer page itself carries no data: it loads, then asks for the key
        page = http.get("/")
        assert page.status_code == 200 and "flocklab viewer" in page.text
        # the API description needs the key, so the docs pages are off
        for docs in ("/docs", "/redoc", "/docs-redoc.js", "/docs-assets/swagger-ui.css"):
            assert http.get(docs).status_code == 404, docs


def test_viewer_and_offline_api_docs(http):
    page = http.get("/")
    assert page.status_code == 200 and page.headers["content-type"].startswith("text/html")
    for asset in ("/static/viewer.js", "/static/npz.js", "/static/viewer.css"):
        assert http.get(asset).status_code == 200, asset
    for path, assets in [("/docs", ("/docs-assets/swagger-ui-bundle.js",
                                    "/docs-assets/swagger-ui.css")),
                         ("/redoc", ("/docs-redoc.js",))]:
        r = http.get(path)
        assert "cdn" not in r.text.lower() and "fonts.googleapis" not in r.text
        assert r.headers["content-security-policy"].startswith("default-src 'self'")
        for asset in assets:
            assert asset in r.text
            got = http.get(asset)
            assert got.status_code == 200 and len(got.content) > 100_000, asset
            assert b"cdn.redoc.ly" not in got.content


def test_api_process_never_loads_plotting_or_the_engine(real_server, real_http):
    """After drawing, the API process has mapped none of matplotlib's or Taichi's
    compiled modules (`import matplotlib` / `import taichi` load them): the drawing ran in
    a child process (a real `flocklab serve`: the test process has loaded both)."""
    http, server = real_http, real_server
    job = submit(http, scenario(n=60, steps=40, every=5))
    assert wait_for(http, job["id"])["status"] == "succeeded"
    done_job = job["id"]
    r = http.get(f"/v1/jobs/{done_job}/render/snapshot.png", params={"width": 128,
                                                                      "height": 128},
                 timeout=120)
    assert r.status_code == 200
    maps = Path(f"/proc/{server.proc.pid}/maps").read_text()
    assert "h5py" in maps  # the check sees the modules the API does load
    for heavy in ("matplotlib", "taichi", "imageio_ffmpeg", "PIL"):
        assert heavy not in maps, heavy
