"""Turning a POST /v1/jobs body into a validated scenario, refusing bad input with a 4xx.

The body is parsed here, not by FastAPI: FastAPI answers a body holding NaN or 1e400 with
a 500 (fastapi#459), and strict scenario types (tuples) validate only from JSON. Pydantic's
JSON parser reads NaN/Infinity/1e400 as floats so that the scenario's finite-number
fields name the offending field; `parse_json_strict` then refuses any non-finite number
that no field caught, so nothing non-finite is ever stored.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from typing import Any

import pydantic_core
from pydantic import ValidationError

from flocklab.schemas import PRESETS, FieldError, Scenario, field_errors, parse_json_strict
from flocklab.service.jobs import check_limits

from .problems import ProblemError, invalid
from .settings import Settings
from .wire import JobRequest


@dataclass(frozen=True)
class Submission:
    scenario: Scenario
    canonical: str  # the scenario as stored (defaults filled in)
    timeout_seconds: float
    request_hash: str  # identifies the request for Idempotency-Key checks


def parse_submission(raw: bytes, settings: Settings) -> Submission:
    """Validate a body against the schema and this service's limits (raises ProblemError)."""
    try:
        data = pydantic_core.from_json(raw)
    except ValueError as exc:
        raise ProblemError(400, "malformed-json", "Malformed JSON", f"the body is not JSON: {exc}"
                           ) from None
    if not isinstance(data, dict):
        raise invalid([FieldError(loc="(root)", msg="the body must be a JSON object",
                                  type="object_type")])
    if "model" in data and "scenario" not in data and "preset" not in data:
        scenario = _validate_scenario(raw, prefix=())
        timeout = None
    else:
        request = _validate(JobRequest, raw)
        timeout = request.timeout_seconds
        if request.scenario is not None:
            scenario = request.scenario
        else:
            assert request.preset is not None
            scenario = _from_preset(request.preset, request.overrides or {})
    try:
        parse_json_strict(raw)
    except ValueError as exc:
        raise invalid([FieldError(loc="(body)", msg=str(exc), type="finite_number")]) from None

    limit_errors = check_limits(scenario, settings.limits())
    if limit_errors:
        raise ProblemError(422, "limit-exceeded", "Over this service's limits",
                           "; ".join(f"{e.loc}: {e.msg}" for e in limit_errors),
                           errors=limit_errors)
    if timeout is None:
        timeout = settings.job_timeout_seconds
    elif timeout > settings.max_job_timeout_seconds:
        raise invalid([FieldError(
            loc="timeout_seconds", type="limit_exceeded",
            msg=f"exceeds this service's limit of {settings.max_job_timeout_seconds:g} s")])
    canonical = scenario.model_dump_json()
    digest = hashlib.sha256(f"{canonical}\n{timeout!r}".encode()).hexdigest()
    return Submission(scenario, canonical, timeout, digest)


def _validate(cls: type[JobRequest], raw: bytes) -> JobRequest:
    try:
        return cls.model_validate_json(raw)
    except ValidationError as exc:
        raise invalid(field_errors(exc)) from None


def _validate_scenario(raw: bytes | str, prefix: tuple[str, ...]) -> Scenario:
    try:
        return Scenario.model_validate_json(raw)
    except ValidationError as exc:
        raise invalid(field_errors(exc, prefix)) from None


def _from_preset(name: str, overrides: dict[str, Any]) -> Scenario:
    if name not in PRESETS:
        known = ", ".join(sorted(PRESETS))
        raise invalid([FieldError(loc="preset", msg=f"unknown preset {name!r}; known: {known}",
                                  type="unknown_preset")])
    merged = _merge(PRESETS[name].build(), overrides)
    # allow_nan: a NaN in the overrides must reach the scenario's validation, which names
    # the field, rather than fail here without a path.
    return _validate_scenario(json.dumps(merged, allow_nan=True), prefix=("overrides",))


def _merge(base: dict[str, Any], overrides: dict[str, Any]) -> dict[str, Any]:
    """Recursive merge of JSON objects; any other value replaces the preset's.

    An override that switches a union member (a different `kind`) replaces the object
    whole, so the old member's fields do not leak into the new one.
    """
    out = dict(base)
    for key, value in overrides.items():
        old = out.get(key)
        if (isinstance(old, dict) and isinstance(value, dict)
                and value.get("kind", old.get("kind")) == old.get("kind")):
            out[key] = _merge(old, value)
        else:
            out[key] = value
    return out
