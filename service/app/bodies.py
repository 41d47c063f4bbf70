"""The request bodies of POST /v1/jobs and POST /v1/sweeps, and how each kind's body is
read into its spec (a `Scenario`, a `Sweep`) before admission (see `submit`).

A job's body is a `JobRequest` (a scenario, or a preset with overrides) or a bare
scenario; a sweep's a `SweepRequest` (a sweep, or a named one) or a bare sweep.
"""

from __future__ import annotations

import json
from typing import Annotated, Any, TypeVar

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from flocklab.schemas import PRESETS, FieldError, Scenario, field_errors
from flocklab.schemas.paths import merge
from flocklab.schemas.sweep import Sweep
from flocklab.schemas.sweep_presets import SWEEP_PRESETS

from .problems import invalid

M = TypeVar("M", bound=BaseModel)

EXAMPLE_SCENARIO: dict[str, Any] = {
    "model": {"kind": "vicsek", "rule": "vicsek", "v0": 0.03, "eta": 2.0},
    "space": {"kind": "periodic", "L": 7.0},
    "neighbours": {"radius": 1.0},
    "initial": {"kind": "random", "N": 300},
    "time": {"steps": 500, "dt": 1.0},
    "recording": {"every": 10, "arrays": ["position", "heading"]},
    "seed": 1,
}


EXAMPLE_SWEEP: dict[str, Any] = {
    "name": "eta-scan",
    "base": {
        "model": {"kind": "vicsek", "rule": "vicsek", "v0": 0.03},
        "space": {"kind": "periodic", "L": 5.0},
        "neighbours": {"radius": 1.0},
        "initial": {"kind": "random", "N": 100},
        "time": {"steps": 500},
        "recording": {"every": 0, "observables_every": 10},
        "seed": 1,
    },
    "axes": [{"path": "model.eta", "values": [0.5, 2.0, 4.0]}],
    "replicas": 2,
    "measure": {"va": {"observable": "polarization", "reduce": "mean", "from_step": 200}},
}


class JobRequest(BaseModel):
    """A submission: a full scenario, or a named preset with optional overrides.

    A bare scenario object (one with a `model` key) is accepted as the body too.
    """

    model_config = ConfigDict(
        extra="forbid", strict=True, frozen=True,
        json_schema_extra={"examples": [
            {"scenario": EXAMPLE_SCENARIO},
            {"preset": "vicsek-1995", "overrides": {"initial": {"N": 1000}},
             "timeout_seconds": 600},
        ]},
    )

    scenario: Scenario | None = Field(default=None, description="The scenario to run.")
    preset: Annotated[str, Field(min_length=1, max_length=100)] | None = Field(
        default=None, description="Name of a preset (see GET /v1/presets).")
    overrides: dict[str, Any] | None = Field(
        default=None, description="Merged into the preset's scenario, object by object "
        "(e.g. {\"initial\": {\"N\": 1000}}); the result is validated as a scenario.")
    timeout_seconds: Annotated[float, Field(gt=0, le=1e9, allow_inf_nan=False)] | None = Field(
        default=None, description="Wall-clock limit for the job; default: the service's.")

    @model_validator(mode="after")
    def _one_source(self) -> JobRequest:
        if (self.scenario is None) == (self.preset is None):
            raise ValueError("give exactly one of 'scenario' and 'preset'")
        if self.overrides is not None and self.preset is None:
            raise ValueError("'overrides' apply to a preset only")
        return self


class SweepRequest(BaseModel):
    """A sweep submission with options: a sweep, or a named one (`flocklab sweep
    preset:NAME`). A bare sweep object is accepted as the body too."""

    model_config = ConfigDict(extra="forbid", strict=True, frozen=True, json_schema_extra={
        "examples": [{"sweep": EXAMPLE_SWEEP, "timeout_seconds": 7200},
                     {"sweep_preset": "vicsek-1995-fig2a"}]})

    sweep: Sweep | None = Field(default=None, description="The sweep to run.")
    sweep_preset: Annotated[str, Field(min_length=1, max_length=100)] | None = Field(
        default=None, description="Name of a named sweep, e.g. 'vicsek-1995-fig2a'.")
    timeout_seconds: Annotated[float, Field(gt=0, le=1e9, allow_inf_nan=False)] | None = Field(
        default=None, description="Wall-clock limit for the whole sweep; default: the "
        "service's job timeout.")

    @model_validator(mode="after")
    def _one_source(self) -> SweepRequest:
        if (self.sweep is None) == (self.sweep_preset is None):
            raise ValueError("give exactly one of 'sweep' and 'sweep_preset'")
        return self


def read_job(data: dict[str, Any], raw: bytes) -> tuple[Scenario, float | None]:
    """A job body's scenario and requested timeout (None: the service's default)."""
    if "model" in data and "scenario" not in data and "preset" not in data:
        return validate(Scenario, raw), None
    request = validate(JobRequest, raw)
    if request.scenario is not None:
        return request.scenario, request.timeout_seconds
    assert request.preset is not None
    return _from_preset(request.preset, request.overrides or {}), request.timeout_seconds


def read_sweep(data: dict[str, Any], raw: bytes) -> tuple[Sweep, float | None]:
    """A sweep body's sweep and requested timeout (None: the service's default)."""
    if "sweep" in data or "sweep_preset" in data:
        request = validate(SweepRequest, raw)
        return (request.sweep or _from_sweep_preset(request.sweep_preset or ""),
                request.timeout_seconds)
    return validate(Sweep, raw), None


def validate(cls: type[M], raw: bytes | str, prefix: tuple[str, ...] = ()) -> M:
    """`cls` from JSON, or a 422 naming each field (under `prefix`)."""
    try:
        return cls.model_validate_json(raw)
    except ValidationError as exc:
        raise invalid(field_errors(exc, prefix)) from None


def _from_sweep_preset(name: str) -> Sweep:
    if name not in SWEEP_PRESETS:
        known = ", ".join(sorted(SWEEP_PRESETS))
        raise invalid([FieldError(loc="sweep_preset", type="unknown_preset",
                                  msg=f"unknown sweep preset {name!r}; known: {known}")])
    return validate(Sweep, json.dumps(SWEEP_PRESETS[name].build()).encode())


def _from_preset(name: str, overrides: dict[str, Any]) -> Scenario:
    if name not in PRESETS:
        known = ", ".join(sorted(PRESETS))
        raise invalid([FieldError(loc="preset", msg=f"unknown preset {name!r}; known: {known}",
                                  type="unknown_preset")])
    merged = merge(PRESETS[name].build(), overrides)
    # allow_nan: a NaN in the overrides must reach the scenario's validation, which names
    # the field, rather than fail here without a path.
    return validate(Scenario, json.dumps(merged, allow_nan=True), ("overrides",))
