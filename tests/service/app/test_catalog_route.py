"""GET /v1/models serves every family's model card (in-process, over
`httpx.ASGITransport` against the real app: the catalog needs no job runtime)."""

from __future__ import annotations

import asyncio
import json

import httpx

from flocklab.schemas import MODELS, describe_models
from flocklab.service.app.factory import create_app
from flocklab.service.app.settings import load_settings

CARD = ("units", "default_plots", "details", "overlays", "constant_speed", "paper_inclusive")


def test_models_route_serves_the_cards(tmp_path):
    app = create_app(load_settings(data_dir=tmp_path / "data"))

    async def get() -> httpx.Response:
        transport = httpx.ASGITransport(app=app)
        async with httpx.AsyncClient(transport=transport, base_url="http://local") as c:
            return await c.get("/v1/models")

    r = asyncio.run(get())
    assert r.status_code == 200
    served = r.json()
    assert served == json.loads(json.dumps(describe_models()))
    assert [m["kind"] for m in served] == list(MODELS)
    for m in served:
        assert set(CARD) <= set(m), m["kind"]
        assert m["default_plots"] == list(MODELS[m["kind"]].default_plots)
