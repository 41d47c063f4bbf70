"""RFC 9457 problem details and the translation of validation errors into them."""

from __future__ import annotations

import json
import math
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from .catalog import MODELS


class FieldError(BaseModel):
    """One invalid field: where it is (a JSON path) and why it is wrong."""

    loc: str = Field(description="Path of the field, e.g. 'model.eta' or 'initial.positions.3'.")
    msg: str = Field(description="What is wrong with it.")
    type: str = Field(default="value_error", description="Machine-readable error kind.")


class Problem(BaseModel):
    """RFC 9457 problem details (`application/problem+json`)."""

    model_config = ConfigDict(extra="allow")

    type: str = Field(default="about:blank", description="URI identifying the problem type.")
    title: str = Field(description="Short summary of the problem type.")
    status: int = Field(description="HTTP status code.")
    detail: str | None = Field(default=None, description="Explanation of this occurrence.")
    instance: str | None = Field(default=None, description="URI of this occurrence.")
    errors: list[FieldError] | None = Field(default=None, description="Invalid fields.")


# Fields whose cross-block checks (Scenario's model validator) start "<field>: message".
CROSS_CHECKED = ("model", "space.dimension", "recording.arrays", "neighbours.kind")


def field_errors(exc: ValidationError, prefix: tuple[str | int, ...] = ()) -> list[FieldError]:
    """Every problem of a pydantic ValidationError, with dotted paths and readable messages."""
    out = []
    for e in exc.errors(include_url=False):
        path = _without_union_tags((*prefix, *e["loc"]))
        loc = ".".join(str(p) for p in path)
        msg = e["msg"]
        if msg.startswith("Value error, "):
            msg = msg[len("Value error, ") :]
        for field in CROSS_CHECKED:  # a scenario's cross-block check names its field
            if not path and msg.startswith(f"{field}: "):
                loc, msg = field, msg[len(field) + 2 :]
        out.append(FieldError(loc=loc or "(root)", msg=msg, type=e["type"]))
    return out


def _without_union_tags(loc: tuple[str | int, ...]) -> list[str | int]:
    """Pydantic puts the chosen union member in the path ('model.vicsek.eta'); users wrote
    'model.eta', so those segments are dropped. A member's fields come right after its tag,
    so a segment just after a dropped tag is a field, even one named like a tag: the
    field 'formation' of model 'formation' ('model.formation.formation.offsets' reads
    'model.formation.offsets')."""
    out: list[str | int] = []
    after_tag = False
    for part in loc:
        tag = isinstance(part, str) and (part in MODELS or part in _MEMBER_TAGS)
        if tag and not after_tag:
            after_tag = True
            continue
        after_tag = False
        out.append(part)
    return out


_MEMBER_TAGS = {"periodic", "plane", "box", "disc", "ball", "lattice", "random", "explicit",
                "path-axis", "zip-axis"}  # the last two: a sweep's axis kinds


def json_safe(value: Any) -> Any:
    """Replace NaN/±Inf and other non-JSON values so an error body can always be encoded."""
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    if isinstance(value, dict):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_safe(v) for v in value]
    if value is None or isinstance(value, str | int | float | bool):
        return value
    return repr(value)


def parse_json_strict(text: str | bytes) -> Any:
    """json.loads that refuses NaN, Infinity and numbers that overflow to ±Inf."""

    def bad_constant(name: str) -> None:
        raise ValueError(f"{name} is not valid JSON (non-finite numbers are not allowed)")

    def parse_float(s: str) -> float:
        v = float(s)
        if not math.isfinite(v):
            raise ValueError(f"number {s[:40]} overflows a 64-bit float")
        return v

    return json.loads(text, parse_constant=bad_constant, parse_float=parse_float)
