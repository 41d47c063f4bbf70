"""Named sweeps reproducing paper figures (`flocklab sweep preset:NAME`).

The protocol (warm-up, averaging window, seeds, sizes) is ours where the paper does not
state it; docs/SWEEPS.md sets it next to the paper's own description.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from .sweep import Sweep, load_sweep


@dataclass(frozen=True)
class SweepPreset:
    name: str
    description: str
    build: Callable[[], dict[str, Any]]
    """Returns the sweep as a JSON-ready dict (validated by `get_sweep_preset`)."""


SWEEP_PRESETS: dict[str, SweepPreset] = {}


def register_sweep_preset(name: str, description: str) -> Callable[[Callable], Callable]:
    def deco(fn: Callable[[], dict[str, Any]]) -> Callable[[], dict[str, Any]]:
        if name in SWEEP_PRESETS:
            raise RuntimeError(f"sweep preset {name!r} registered twice")
        SWEEP_PRESETS[name] = SweepPreset(name, description, fn)
        return fn

    return deco


def get_sweep_preset(name: str) -> Sweep:
    """The named sweep, validated (KeyError naming the known ones)."""
    if name not in SWEEP_PRESETS:
        raise KeyError(f"unknown sweep preset {name!r}; known: {', '.join(sorted(SWEEP_PRESETS))}")
    return load_sweep(SWEEP_PRESETS[name].build())


WARM_UP = 2000  # steps left out of the time average (the ordered state forms by then)


def _vicsek_1995_base(n: int, L: float, eta: float, steps: int) -> dict[str, Any]:
    """Vicsek et al. 1995's setting: v0 = 0.03, r = 1 ('in or on' the circle), dt = 1,
    the position moving with the new heading, the polarization (the only observable the
    figures use, so the cheapest run) every 10 steps, no frames."""
    return {
        "name": "vicsek-1995",
        "model": {"kind": "vicsek", "rule": "vicsek", "v0": 0.03, "eta": eta,
                  "position_update": "new_heading"},
        "space": {"kind": "periodic", "L": L},
        "neighbours": {"radius": 1.0, "inclusive": True},
        "initial": {"kind": "random", "N": n},
        "time": {"steps": steps, "dt": 1.0},
        "recording": {"every": 0, "observables_every": 10, "observables": ["polarization"]},
        "seed": 1,
    }


def _measures() -> dict[str, Any]:
    """v_a averaged over the window after the warm-up, and its fluctuation (a fresh dict
    per call: a caller may edit the sweep it gets)."""
    return {
        "va": {"observable": "polarization", "reduce": "mean", "from_step": WARM_UP},
        "va_std": {"observable": "polarization", "reduce": "std", "from_step": WARM_UP},
    }


@register_sweep_preset(
    "vicsek-1995-fig2a",
    "Vicsek et al. 1995 Fig. 2a: polarization v_a vs noise eta = 0.5..5.0 at density 4 for "
    "N = 100, 400, 4000 (8/4/2 seeds, 6000/6000/8000 steps, mean from step 2000).")
def vicsek_1995_fig2a() -> dict[str, Any]:
    sizes = [100, 400, 4000]
    return {
        "name": "vicsek-1995-fig2a",
        "description": "v_a = |sum_i e^{i theta_i}| / N against eta at rho = N / L^2 = 4.",
        "base": _vicsek_1995_base(100, 5.0, 0.5, 6000),
        "axes": [
            {"path": "model.eta", "values": [round(0.5 * k, 10) for k in range(1, 11)]},
            {"zip": [
                {"path": "initial.N", "values": sizes},
                {"path": "space.L", "values": [math.sqrt(n / 4) for n in sizes]},
                {"path": "replicas", "values": [8, 4, 2]},
                {"path": "time.steps", "values": [6000, 6000, 8000]},
            ]},
        ],
        "measure": _measures(),
        "series": ["polarization"],
        "keep": "summaries",
    }


@register_sweep_preset(
    "vicsek-1995-fig2b",
    "Vicsek et al. 1995 Fig. 2b: polarization v_a vs density rho = N / 400 = 0.1..10 at "
    "L = 20, eta = 2 (4 seeds, 6000 steps, mean from step 2000).")
def vicsek_1995_fig2b() -> dict[str, Any]:
    densities = [0.1, 0.25, 0.5, 1, 2, 3, 4, 6, 8, 10]
    return {
        "name": "vicsek-1995-fig2b",
        "description": "v_a against rho = N / L^2 at L = 20, eta = 2.",
        "base": _vicsek_1995_base(400, 20.0, 2.0, 6000),
        "axes": [{"path": "initial.N", "values": [round(rho * 400) for rho in densities]}],
        "replicas": 4,
        "measure": _measures(),
        "series": ["polarization"],
        "keep": "summaries",
    }


# The finite-size-scaling preset: Chaté, Ginelli, Grégoire & Raynaud's setting (PRE 77,
# 046113 (2008): v0 = 0.5, rho = 2, r = 1), flocklab's angular noise (full width eta).
FSS_SIDES = (8, 16, 32)
FSS_DENSITY = 2
FSS_ETAS = tuple(round(2.2 + 0.2 * k, 10) for k in range(11))  # 2.2 .. 4.2
FSS_STEPS, FSS_WARM_UP = 5000, 1000


@register_sweep_preset(
    "vicsek-fss",
    "Finite-size scaling of the Vicsek transition: Binder cumulant G and susceptibility "
    "chi of the polarization vs eta = 2.2..4.2 at density 2, v0 = 0.5, for L = 8, 16, 32 "
    "(8/4/4 seeds, 5000 steps, statistics from step 1000).")
def vicsek_fss() -> dict[str, Any]:
    base = _vicsek_1995_base(FSS_DENSITY * FSS_SIDES[0] ** 2, FSS_SIDES[0], FSS_ETAS[0],
                             FSS_STEPS)
    base["name"] = "vicsek-fss"
    base["model"]["v0"] = 0.5
    base["recording"]["observables_every"] = 5

    def stat(reduce: str) -> dict[str, Any]:
        return {"observable": "polarization", "reduce": reduce, "from_step": FSS_WARM_UP}

    return {
        "name": "vicsek-fss",
        "description": "G = 1 - <phi^4> / (3 <phi^2>^2) and chi = N (<phi^2> - <phi>^2) of "
                       "phi = |sum_i e^{i theta_i}| / N against eta, per L at rho = N / L^2 "
                       "= 2.",
        "base": base,
        "axes": [
            {"path": "model.eta", "values": list(FSS_ETAS)},
            {"zip": [
                {"path": "space.L", "values": list(FSS_SIDES)},
                {"path": "initial.N", "values": [FSS_DENSITY * s * s for s in FSS_SIDES]},
                {"path": "replicas", "values": [8, 4, 4]},
            ]},
        ],
        "measure": {"G": stat("binder"), "chi": stat("susceptibility"),
                    "phi": stat("moments"), "tau": stat("tau_int")},
        "labels": {"model.eta": "η", "space.L": "L", "initial.N": "N", "G": "G",
                   "chi": "χ", "phi_m1": "⟨φ⟩", "phi_m2": "⟨φ²⟩", "phi_m4": "⟨φ⁴⟩",
                   "phi_tau": "τ_int(φ)", "tau": "τ_int(φ)"},
        "keep": "summaries",
    }
