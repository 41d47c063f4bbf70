"""Issue 28, finding 7: render work bounded. The cache of drawn pictures grew without
bound from GETs with new options and ignored the disk reserve; two render slots were
shared by everyone, so one client asking for movies made every other client wait. A real
server on 127.0.0.1; clients told apart by their source address (127.0.0.0/8 is loopback)."""

from __future__ import annotations

import threading
import time

import httpx
import pytest

from tests.service.conftest import _cleanup
from tests.service.svc_helpers import assert_problem, scenario, submit, wait_for

pytest.importorskip("matplotlib")
CACHE_BYTES = 120_000


def _finished(http: httpx.Client, **kw) -> str:
    job = submit(http, scenario(**kw))
    assert wait_for(http, job["id"])["status"] == "succeeded"
    return job["id"]


def _cached(server, job_id: str) -> dict[str, int]:
    folder = server.data_dir / "results" / job_id / "render"
    return {p.name: p.stat().st_size for p in folder.glob("*") if not p.name.startswith(".")}


@pytest.mark.slow
def test_the_cache_stays_within_its_bound_least_recently_used_first(make_server):
    s = make_server({"FLOCKLAB_RENDER_CACHE_BYTES": str(CACHE_BYTES)})
    with httpx.Client(base_url=s.url, timeout=120) as http:
        job = _finished(http, n=200, steps=20, every=5)
        path = f"/v1/jobs/{job}/render/snapshot.png"
        first = http.get(path, params={"width": 400, "height": 400})
        assert first.status_code == 200, first.text
        (kept,) = _cached(s, job)
        sizes = []
        for w in range(420, 720, 50):
            r = http.get(path, params={"width": w, "height": 400})
            assert r.status_code == 200, r.text
            sizes.append(len(r.content))
            # The first picture is asked for again each time: the most recently used.
            assert http.get(path, params={"width": 400, "height": 400}).content == first.content
            cached = _cached(s, job)
            assert sum(cached.values()) <= CACHE_BYTES, cached
            assert kept in cached
        assert sum(sizes) + len(first.content) > 2 * CACHE_BYTES  # eviction was needed
        assert len(_cached(s, job)) < len(sizes) + 1


@pytest.mark.slow
def test_no_new_pictures_below_the_disk_reserve(make_server, tmp_path):
    data = tmp_path / "reserve"
    s = make_server(data_dir=data)
    with httpx.Client(base_url=s.url, timeout=120) as http:
        job = _finished(http)
        path = f"/v1/jobs/{job}/render/snapshot.png"
        assert http.get(path, params={"width": 300, "height": 300}).status_code == 200
    _cleanup(s)
    assert len(_cached(s, job)) == 1
    # The same data on a disk that is now (by this reserve) full.
    s = make_server({"FLOCKLAB_MIN_FREE_DISK_BYTES": str(2**60)}, data_dir=data)
    with httpx.Client(base_url=s.url, timeout=120) as http:
        r = http.get(path, params={"width": 320, "height": 300})
        body = assert_problem(r, 503)
        assert body["type"].endswith("insufficient-storage")
        assert int(r.headers["Retry-After"]) >= 1
        assert "/" not in body["detail"]
    # The cache gave back what it held before refusing.
    assert _cached(s, job) == {}


def _client(url: str, source: str) -> httpx.Client:
    return httpx.Client(base_url=url, timeout=300,
                        transport=httpx.HTTPTransport(local_address=source))


@pytest.mark.slow
def test_one_client_drawing_movies_does_not_hold_every_slot(make_server):
    s = make_server({"FLOCKLAB_RENDER_SLOTS": "2", "FLOCKLAB_RENDER_SLOTS_PER_CLIENT": "1"})
    with httpx.Client(base_url=s.url, timeout=120) as http:
        job = _finished(http, n=100, steps=250, every=1)
    done: list[tuple[str, float]] = []
    started = time.monotonic()

    def movie(fps: float) -> None:
        with _client(s.url, "127.0.0.2") as a:
            r = a.get(f"/v1/jobs/{job}/render/movie.mp4", params={"fps": fps})
            assert r.status_code == 200, r.text
            done.append(("movie", time.monotonic() - started))

    hostile = [threading.Thread(target=movie, args=(fps,)) for fps in (10, 11)]
    for t in hostile:
        t.start()
    time.sleep(1.5)  # the movies have taken their slots
    with _client(s.url, "127.0.0.3") as b:
        r = b.get(f"/v1/jobs/{job}/render/snapshot.png", params={"width": 200, "height": 200})
        assert r.status_code == 200, r.text
        done.append(("snapshot", time.monotonic() - started))
    for t in hostile:
        t.join()
    # The other client's picture came while the first client's movies were still drawing.
    assert done[0][0] == "snapshot", done
    assert [k for k, _ in done].count("movie") == 2
