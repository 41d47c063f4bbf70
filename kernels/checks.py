"""The papers' monotone quantities, checked on a run's observed series.

Paper 000 proves that W (fixed graph, eq. 5) and Q (switching, eq. 10) never increase in
continuous time. The engine's steps are discrete: when dt does not resolve the stiffest
pair (two agents pressed close, where the barrier's curvature grows as 1/s^4), the
discrete Q rises, and the run is no longer the paper's dynamics even though it stays
finite. Each run reports, per quantity the model declares (`ModelParams.non_increasing`),
whether it held, so that a user sees the warning instead of a plausible-looking flock.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from flocklab.schemas import Scenario

# A rise smaller than this, relative to the series' largest magnitude, is rounding: the
# float64 sums of N terms, or float32 state (observables are summed in float64 either way).
RISE_TOLERANCE = {"float64": 1e-9, "float32": 1e-5}


def monotone_checks(claims: dict[str, str], obs: dict[str, np.ndarray],
                    precision: str) -> dict[str, Any]:
    """{name_non_increasing: {held, rises, largest_rise, first_rise_time, claim}} for each
    claimed quantity that was observed; `largest_rise` is relative to max |series|."""
    out: dict[str, Any] = {}
    for name, claim in claims.items():
        series = obs.get(name)
        if series is None or len(series) < 2:
            continue
        scale = float(np.abs(series).max()) or 1.0
        rise = np.diff(series) / scale
        bad = np.flatnonzero(rise > RISE_TOLERANCE[precision])
        out[f"{name}_non_increasing"] = {
            "held": bool(bad.size == 0),
            "rises": int(bad.size),
            "largest_rise": float(max(rise.max(), 0.0)),
            "first_rise_time": float(obs["time"][bad[0] + 1]) if bad.size else None,
            "claim": claim,
        }
    return out


def run_checks(scenario: Scenario, obs: dict[str, np.ndarray]) -> dict[str, Any]:
    """The summary's `checks` entry for a run ({} when its model claims nothing). The
    papers' energies are proved non-increasing on metric graphs, whose links switch where
    the saturated potential is flat (at R); a topological neighbour joins or leaves at any
    distance, so no claim is checked for those runs."""
    nb = scenario.neighbours
    claims = {} if nb is not None and nb.topological else scenario.model.non_increasing()
    checks = monotone_checks(claims, obs, scenario.precision)
    return {"checks": checks} if checks else {}


def warnings(checks: dict[str, Any]) -> list[str]:
    """One line per quantity that rose, for a command's standard error."""
    return [f"{name.removesuffix('_non_increasing')} rose {c['rises']} time(s), by up to "
            f"{c['largest_rise']:.3g} of its size, first at t = {c['first_rise_time']:g} "
            f"({c['claim']}): dt is too large for the dynamics (a pair pressed close); "
            "try a smaller time.dt"
            for name, c in checks.items() if not c["held"]]


def time_to_converge(t: np.ndarray, values: np.ndarray, tol: float) -> float | None:
    """First time after which `values` stays below `tol` to the end (None: never)."""
    if len(values) == 0 or not values[-1] < tol:
        return None
    above = np.nonzero(~(values < tol))[0]
    return float(t[0] if len(above) == 0 else t[above[-1] + 1])
