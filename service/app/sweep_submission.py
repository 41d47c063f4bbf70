"""Turning a POST /v1/sweeps body into a validated sweep, refusing bad input with a 4xx.

Parsed by hand like a job's body (see `submission`): FastAPI would answer NaN or 1e400
with a 500. The schema first (unequal `zip` lists, empty axes, overlapping paths), then
`check_sweep`: the run count before expanding, then the runs (unknown paths, a run whose
scenario is invalid, naming the run and the field), the total agent-steps and each run
against the per-job limits.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from typing import TypeVar

import pydantic_core
from pydantic import BaseModel, ValidationError

from flocklab.schemas import FieldError, field_errors, parse_json_strict
from flocklab.schemas.sweep import Sweep, SweepError
from flocklab.schemas.sweep_presets import SWEEP_PRESETS
from flocklab.service.jobs.sweep_limits import SweepLimitError, check_sweep

from .problems import ProblemError, invalid
from .settings import Settings
from .sweep_wire import SweepRequest

M = TypeVar("M", bound=BaseModel)


@dataclass(frozen=True)
class SweepSubmission:
    sweep: Sweep
    canonical: str  # the sweep as stored (defaults filled in)
    model_kind: str
    max_agents: int  # the largest N of its runs
    runs_total: int
    timeout_seconds: float
    request_hash: str  # identifies the request for Idempotency-Key checks


def parse_sweep_submission(raw: bytes, settings: Settings) -> SweepSubmission:
    """Validate a body against the sweep schema and this service's limits (raises
    ProblemError)."""
    try:
        data = pydantic_core.from_json(raw)
    except ValueError as exc:
        raise ProblemError(400, "malformed-json", "Malformed JSON", f"the body is not JSON: {exc}"
                           ) from None
    if not isinstance(data, dict):
        raise invalid([FieldError(loc="(root)", msg="the body must be a JSON object",
                                  type="object_type")])
    if "sweep" in data or "sweep_preset" in data:
        request = _validate(SweepRequest, raw)
        timeout = request.timeout_seconds
        sweep = request.sweep or _from_preset(request.sweep_preset or "")
    else:
        sweep, timeout = _validate(Sweep, raw), None
    try:
        parse_json_strict(raw)
    except ValueError as exc:
        raise invalid([FieldError(loc="(body)", msg=str(exc), type="finite_number")]) from None

    try:
        scan = check_sweep(sweep, settings.limits())
    except SweepError as exc:  # an unknown path, a run whose scenario is invalid
        raise invalid(exc.errors) from None
    except SweepLimitError as exc:
        raise ProblemError(422, "limit-exceeded", "Over this service's limits", str(exc),
                           errors=exc.errors, **exc.numbers) from None

    if timeout is None:
        timeout = settings.job_timeout_seconds
    elif timeout > settings.max_job_timeout_seconds:
        raise invalid([FieldError(
            loc="timeout_seconds", type="limit_exceeded",
            msg=f"exceeds this service's limit of {settings.max_job_timeout_seconds:g} s")])
    canonical = sweep.model_dump_json()
    digest = hashlib.sha256(f"sweep\n{canonical}\n{timeout!r}".encode()).hexdigest()
    return SweepSubmission(
        sweep=sweep, canonical=canonical, model_kind=scan.model_kind,
        max_agents=scan.max_agents, runs_total=scan.runs,
        timeout_seconds=timeout, request_hash=digest)


def _from_preset(name: str) -> Sweep:
    if name not in SWEEP_PRESETS:
        known = ", ".join(sorted(SWEEP_PRESETS))
        raise invalid([FieldError(loc="sweep_preset", type="unknown_preset",
                                  msg=f"unknown sweep preset {name!r}; known: {known}")])
    return _validate(Sweep, json.dumps(SWEEP_PRESETS[name].build()).encode())


def _validate(cls: type[M], raw: bytes) -> M:
    try:
        return cls.model_validate_json(raw)
    except ValidationError as exc:
        raise invalid(field_errors(exc)) from None
