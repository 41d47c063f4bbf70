"""The client's sweeps, sync and async, against a real `flocklab serve` on 127.0.0.1."""

from __future__ import annotations

import asyncio
import importlib.util
import json
from typing import Any

import numpy as np
import pytest

from flocklab.clients import (
    AsyncClient,
    Client,
    Conflict,
    NotFound,
    SweepFailed,
    SweepJob,
    UnprocessableEntity,
)
from flocklab.schemas.status import SweepStatus
from flocklab.schemas.sweep import Sweep
from tests.clients.conftest import scenario


def spec(etas: list[float] | None = None, replicas: int = 2, steps: int = 40,
         n: int = 36) -> dict[str, Any]:
    base = scenario(n=n, steps=steps, every=0)
    base["space"]["L"] = 3.0
    return {
        "name": "client-scan",
        "base": base,
        "axes": [{"path": "model.eta", "values": etas or [0.2, 1.0, 3.0]}],
        "replicas": replicas,
        "measure": {"va": {"observable": "polarization", "reduce": "mean", "from_step": 10},
                    "va_end": {"observable": "polarization", "reduce": "final"}},
    }


def test_sync_sweep_wait_returns_the_table(server):
    with Client(server.url, transport=server.transport) as c:
        handle = c.sweep(Sweep.model_validate_json(json.dumps(spec())))
        assert isinstance(handle, SweepJob) and isinstance(handle.state, SweepStatus)
        assert handle.state.runs_total == 6
        table = handle.wait(timeout=300)
        assert isinstance(table, np.ndarray) and table.dtype.names is not None
        assert table.dtype.names[:2] == ("point", "model.eta")
        assert table["point"].dtype == np.int64 and table["va_mean"].dtype == np.float64
        np.testing.assert_array_equal(table["model.eta"], [0.2, 1.0, 3.0])
        np.testing.assert_array_equal(table["va_count"], [2, 2, 2])
        assert np.all((table["va_mean"] > 0) & (table["va_mean"] <= 1))
        # Low noise orders the flock more than high noise.
        assert table["va_mean"][0] > table["va_mean"][2]

        status = handle.status()
        assert status.status == "succeeded" and status.runs_done == 6
        assert status.progress == 1.0 and status.results == "available"
        # The JSON table the handle parsed is the CSV the service stores.
        csv = handle.csv().splitlines()
        assert csv[0].split(",") == list(table.dtype.names)
        assert len(csv) == 1 + len(table)
        runs = handle.runs()
        assert len(runs) == 6 and set(runs["status"]) == {"completed"}
        assert runs["seed"].tolist() == [7, 8] * 3  # seed + replica at every grid point

        if importlib.util.find_spec("pandas") is not None:
            df = handle.table_frame()
            assert list(df.columns) == list(table.dtype.names)
            np.testing.assert_array_equal(df["va_mean"].to_numpy(), table["va_mean"])
        else:
            with pytest.raises(ImportError, match="pandas"):
                handle.table_frame()

        assert handle.id in [s.id for s in c.sweeps(status="succeeded")]
        assert c.get_sweep(handle.id).state.runs_done == 6
        assert handle.spec() == Sweep.model_validate_json(json.dumps(spec()))
        with pytest.raises(Conflict):
            handle.cancel()


def test_sync_sweep_errors_and_cancel(server):
    with Client(server.url, transport=server.transport) as c:
        bad = spec(etas=[1.0, -2.0])
        with pytest.raises(UnprocessableEntity) as err:
            c.sweep(bad)
        assert any(e["loc"].endswith("model.eta") and e["loc"].startswith("runs[2]")
                   for e in err.value.errors), err.value.errors
        with pytest.raises(UnprocessableEntity) as err:
            c.sweep(sweep_preset="no-such-sweep")
        assert err.value.errors[0]["loc"] == "sweep_preset"
        with pytest.raises(NotFound):
            c.get_sweep("00000000-0000-4000-8000-000000000000")

        long = c.sweep(spec(etas=[0.5, 1.0, 1.5, 2.0], replicas=5, steps=3000, n=300),
                       timeout_seconds=600)
        assert long.state.timeout_seconds == 600
        status = long.cancel()
        assert status.cancel_requested
        with pytest.raises(SweepFailed) as failed:
            long.wait(timeout=120)
        assert failed.value.status.status == "cancelled"
        assert failed.value.status.runs_done < 20


def test_async_sweep(server):
    async def main() -> tuple[np.ndarray, SweepStatus, np.ndarray]:
        async with AsyncClient(server.url, transport=server.async_transport) as c:
            handle = await c.sweep(spec(etas=[0.5, 2.5], replicas=1),
                                   idempotency_key="async-sweep-1")
            again = await c.sweep(spec(etas=[0.5, 2.5], replicas=1),
                                  idempotency_key="async-sweep-1")
            assert again.id == handle.id
            table = await handle.wait(timeout=300)
            status = await handle.status()
            ids = [s.id async for s in c.sweeps()]
            assert handle.id in ids
            return table, status, await (await c.get_sweep(handle.id)).runs()

    table, status, runs = asyncio.run(main())
    np.testing.assert_array_equal(table["model.eta"], [0.5, 2.5])
    np.testing.assert_array_equal(table["va_count"], [1, 1])
    # One replica: the mean over replicas is the run's own measure; sd is missing.
    np.testing.assert_array_equal(table["va_mean"], runs["va"])
    assert np.isnan(table["va_sd"]).all()
    assert status.status == "succeeded" and status.runs_total == 2
