"""The image's cache warm-up (docker/warm_cache.py) covers every model and option.

A model or option added later without a preset or example would otherwise compile on its
first job in a fresh container; this fails instead.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path
from typing import Literal, get_args, get_origin

from flocklab.schemas.catalog import MODELS

ROOT = Path(__file__).resolve().parents[2]


def _warm_scenarios():
    spec = importlib.util.spec_from_file_location("warm_cache", ROOT / "docker/warm_cache.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return [sc for _, sc in module.scenarios(ROOT / "examples")]


def test_warm_up_covers_every_model_kind_and_option_value():
    scenarios = _warm_scenarios()
    assert {sc.model.kind for sc in scenarios} == set(MODELS)
    for kind, cls in MODELS.items():
        for name, field in cls.model_fields.items():
            if name == "kind" or get_origin(field.annotation) is not Literal:
                continue
            used = {getattr(sc.model, name) for sc in scenarios if sc.model.kind == kind}
            assert used == set(get_args(field.annotation)), (kind, name)
