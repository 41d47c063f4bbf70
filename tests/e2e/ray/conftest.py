"""The Ray tests' cluster: one real two-node Ray cluster on 127.0.0.1 for the session,
started here and always stopped at the end (only our own processes; see cluster.py).
Skipped, with the reason, where `ray` is not installed."""

from __future__ import annotations

import os
from collections.abc import Iterator

import pytest

pytest.importorskip("ray", reason="the Ray executor tests need `pip install 'flocklab[ray]'`")

from bench.local_ray import RAY_ENV, LocalRayCluster


@pytest.fixture(scope="session")
def ray_cluster() -> Iterator[LocalRayCluster]:
    # The drivers (the CLI, the service's workers) started by the tests inherit these.
    saved = {k: os.environ.get(k) for k in RAY_ENV}
    os.environ.update(RAY_ENV)
    cluster = LocalRayCluster(cpus_head=1, cpus_node=1).start()
    try:
        yield cluster
    finally:
        cluster.stop()
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v

