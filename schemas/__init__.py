"""flocklab's wire contract: pydantic only (no taichi, no fastapi)."""

from .catalog import MODELS, ModelParams, describe_models
from .common import (
    Ball,
    Box,
    Disc,
    ExplicitInitial,
    Lattice,
    Neighbours,
    PeriodicBox,
    Plane,
    RandomInitial,
    Recording,
    TimeSpec,
)
from .presets import PRESETS
from .problems import FieldError, Problem, field_errors, parse_json_strict
from .scenario import Scenario, get_preset
from .vicsek import VicsekParams

__all__ = [
    "MODELS",
    "PRESETS",
    "Ball",
    "Box",
    "Disc",
    "ExplicitInitial",
    "FieldError",
    "Lattice",
    "ModelParams",
    "Neighbours",
    "PeriodicBox",
    "Plane",
    "Problem",
    "RandomInitial",
    "Recording",
    "Scenario",
    "TimeSpec",
    "VicsekParams",
    "describe_models",
    "field_errors",
    "get_preset",
    "parse_json_strict",
]
