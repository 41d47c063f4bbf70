"""Named scenarios that reproduce the papers' runs. Each model family registers its own."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class Preset:
    name: str
    description: str
    build: Callable[[], dict[str, Any]]
    """Returns the scenario as a JSON-ready dict (validated by `scenario.get_preset`)."""


PRESETS: dict[str, Preset] = {}


def register_preset(name: str, description: str) -> Callable[[Callable], Callable]:
    def deco(fn: Callable[[], dict[str, Any]]) -> Callable[[], dict[str, Any]]:
        if name in PRESETS:
            raise RuntimeError(f"preset {name!r} registered twice")
        PRESETS[name] = Preset(name, description, fn)
        return fn

    return deco

