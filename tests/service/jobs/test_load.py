"""Fifty concurrent submissions through the client: none lost; the worker's memory stays
flat over them (R11, R15)."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from flocklab import clients
from tests.service.svc_helpers import scenario


def _rss(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) * 1024
    raise AssertionError("no VmRSS")


def _worker(server) -> int:
    pids = [p for p in server.children()
            if b"spawn_main" in Path(f"/proc/{p}/cmdline").read_bytes()]
    assert len(pids) == 1, pids
    return pids[0]


@pytest.mark.slow
def test_fifty_concurrent_submissions_none_lost_and_worker_memory_flat(server):
    sizes = [50, 200, 500, 1000]
    with clients.Client(server.url, transport=server.transport) as c:
        first = c.submit(scenario(n=1000, steps=20, every=5)).wait(timeout=120)
        assert first.status == "succeeded"
        pid = _worker(server)
        rss_first = _rss(pid)
        before = {j.id for j in c.jobs()}

        def submit(i: int) -> clients.Job | clients.TooManyRequests:
            try:
                return c.submit(scenario(n=sizes[i % 4], steps=20, every=5, seed=i))
            except clients.TooManyRequests as exc:
                return exc

        with ThreadPoolExecutor(50) as pool:
            outcomes = list(pool.map(submit, range(50)))
        accepted = [o for o in outcomes if isinstance(o, clients.Job)]
        refused = [o for o in outcomes if isinstance(o, clients.TooManyRequests)]
        assert len(accepted) + len(refused) == 50
        assert len(accepted) >= 50 - 1  # the queue holds 64; at most a straggler refused
        assert len({j.id for j in accepted}) == len(accepted)
        listed = [j.id for j in c.jobs()]
        new = [i for i in listed if i not in before]
        assert sorted(new) == sorted(j.id for j in accepted)  # stored once each, none lost
        for job in accepted:
            assert job.wait(timeout=300).status == "succeeded", job.data

        assert _worker(server) == pid  # the same worker ran them all
        rss_after = _rss(pid)
    print(f"worker RSS after the first job {rss_first / 2**20:.1f} MiB, "
          f"after 50 more {rss_after / 2**20:.1f} MiB")
    assert rss_after <= 1.10 * rss_first, (rss_first, rss_after)
