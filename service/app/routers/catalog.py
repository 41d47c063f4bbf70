"""/v1/models and /v1/presets: what can be run, with each model's JSON Schema."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter

from flocklab.schemas import PRESETS, describe_models, get_preset

from ..problems import ProblemError

router = APIRouter(tags=["catalog"])


@router.get("/models", summary="The model catalog",
            description="Every model family: kind, paper, equations, parameters with "
            "defaults and descriptions, and the JSON Schema of its `model` block.",
            responses={401: {}})
def models() -> list[dict[str, Any]]:
    return describe_models()


@router.get("/models/{kind}", summary="One model's JSON Schema", responses={401: {}, 404: {}})
def model_schema(kind: str) -> dict[str, Any]:
    for m in describe_models():
        if m["kind"] == kind:
            return m["json_schema"]
    known = ", ".join(m["kind"] for m in describe_models())
    raise ProblemError(404, "model-not-found", "Unknown model",
                       f"no model of kind {kind!r}; known: {known}")


@router.get("/presets", summary="Named scenarios reproducing the papers' runs",
            description="Each preset with its description and full scenario; submit one "
            "with `{\"preset\": name}`.", responses={401: {}})
def presets() -> list[dict[str, Any]]:
    return [{"name": p.name, "description": p.description,
             "scenario": get_preset(p.name).model_dump(mode="json")}
            for p in PRESETS.values()]
