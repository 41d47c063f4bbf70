"""Observables against time (one panel each, convergence time marked) and sweep plots
(each measure against the first axis, one curve per value of the second)."""

from __future__ import annotations

from typing import Any

import numpy as np

from .errors import RenderInputError
from .figure import check_size
from .run_data import RunData, SweepData

# Decaying quantities read best on a log scale.
LOG_SCALE = ("disagreement", "error", "mismatch", "spread")


def default_observables(run: RunData) -> list[str]:
    """The card's default plots this run recorded, else its first three observables."""
    have = run.observables
    names = [n for n in run.drawing.default_plots if n in have]
    return names or [n for n in have if n not in ("step", "time")][:3]


def draw_observables(fig: Any, run: RunData, names: list[str] | None, width: int,
                     height: int) -> list[str]:
    """Panels of the named observables against time; returns the names drawn."""
    check_size(width, height)
    obs = run.observables
    names = names or default_observables(run)
    if not names:  # nothing but step and time: recording.observables = [] (or no file)
        raise RenderInputError(f"{run.folder.name}: no observables were recorded", status=404)
    unknown = [n for n in names if n not in obs or n in ("step", "time")]
    if unknown:
        known = ", ".join(n for n in obs if n not in ("step", "time"))
        raise RenderInputError(f"unknown observable(s) {', '.join(unknown)}; this run has: "
                               f"{known}", loc="names")
    t = obs["time"]
    axes = fig.subplots(len(names), 1, sharex=True, squeeze=False)[:, 0]
    conv = run.convergence
    for ax, name in zip(axes, names, strict=True):
        y = obs[name]
        ax.plot(t, y, lw=1.2)
        ax.set_ylabel(name, fontsize=8)
        positive = y[np.isfinite(y)]
        if any(s in name for s in LOG_SCALE) and len(positive) and positive.min() > 0:
            ax.set_yscale("log")
        if name in conv:
            ax.axvline(conv[name], c="tab:red", ls="--", lw=1)
            ax.annotate(f"converged t = {conv[name]:.4g}", (conv[name], 0.92),
                        xycoords=("data", "axes fraction"), fontsize=8, c="tab:red",
                        ha="left", xytext=(3, 0), textcoords="offset points")
        ax.grid(alpha=0.3)
    # a convergence time of a quantity not plotted is still worth marking
    for q, tc in conv.items():
        if q not in names:
            for ax in axes:
                ax.axvline(tc, c="tab:red", ls=":", lw=0.8)
            axes[0].annotate(f"{q} converged t = {tc:.4g}", (tc, 0.8),
                             xycoords=("data", "axes fraction"), fontsize=7, c="tab:red",
                             xytext=(3, 0), textcoords="offset points")
    unit = run.drawing.units.get("time")
    axes[-1].set_xlabel(f"time ({unit})" if unit else "time")
    fig.suptitle(f"{run.name}: N = {run.n_agents}", fontsize=10)
    fig.tight_layout()
    return names


def draw_sweep(fig: Any, sweep: SweepData, names: list[str] | None, width: int,
               height: int) -> list[str]:
    """Each measure against the first axis, one curve per value of the second axis, error
    bars from the replicas' standard error (else their standard deviation; where a point
    has one replica, its tau_int-based error `_err` when the table has one), labelled
    with the sweep's symbols (`SweepData.label`). A design sweep without axes: each
    measure against each design parameter; names ["sensitivity"] (the default when the
    folder has sensitivity.csv): the sensitivity bars (sensitivity_plot.py)."""
    check_size(width, height)
    from .sensitivity_plot import draw_design, draw_sensitivity, has_sensitivity

    if names == ["sensitivity"] or (names is None and has_sensitivity(sweep.folder)):
        if not has_sensitivity(sweep.folder):
            raise RenderInputError(f"{sweep.folder}: no sensitivity.csv (a sweep with an "
                                   "analysis writes it when every run has finished)",
                                   loc="names")
        draw_sensitivity(fig, sweep, width, height)
        return ["sensitivity"]
    measures = names or sweep.measures
    unknown = [m for m in measures if f"{m}_mean" not in sweep.columns]
    if unknown or not measures:
        raise RenderInputError(f"unknown measure(s) {', '.join(unknown) or '(none)'}; "
                               f"the sweep has: {', '.join(sweep.measures)}", loc="names")
    spec = sweep.spec.get("sweep") if isinstance(sweep.spec.get("sweep"), dict) else {}
    if spec.get("design") and not spec.get("axes"):
        return draw_design(fig, sweep, measures, width, height)
    x_axis = sweep.axes[0]
    group = sweep.axes[1] if len(sweep.axes) > 1 else None
    x, ticks = _axis_positions(sweep, x_axis)
    keys = sweep.text[group] if group else [""] * len(x)
    groups = list(dict.fromkeys(keys))  # in table order
    axes = fig.subplots(len(measures), 1, sharex=True, squeeze=False)[:, 0]
    for ax, m in zip(axes, measures, strict=True):
        mean = sweep.columns[f"{m}_mean"]
        err = sweep.columns.get(f"{m}_sem", sweep.columns.get(f"{m}_sd"))
        if err is not None and f"{m}_err" in sweep.columns:
            err = np.where(np.isfinite(err), err, sweep.columns[f"{m}_err"])
        for g in groups:
            rows = np.array([k == g for k in keys])
            order = np.argsort(x[rows], kind="stable")
            yerr = None if err is None else np.nan_to_num(err[rows][order])
            ax.errorbar(x[rows][order], mean[rows][order], yerr=yerr, marker="o", ms=4,
                        capsize=3, lw=1.2,
                        label=f"{sweep.label(group)} = {g}" if group else None)
        symbol = sweep.label(m)  # a symbol (G, χ) reads at the size of the tick labels
        ax.set_ylabel(symbol, fontsize=11 if len(symbol) <= 8 else 8)
        ax.grid(alpha=0.3)
        if group is not None:
            ax.legend(fontsize=7)
    if ticks is not None:
        axes[-1].set_xticks(range(len(ticks)), ticks)
    axes[-1].set_xlabel(sweep.label(x_axis))
    bars = "sem" if any(f"{m}_sem" in sweep.columns for m in measures) else "sd"
    fig.suptitle(f"{sweep.name}: mean ± {bars} over replicas", fontsize=10)
    fig.tight_layout()
    return measures


def _axis_positions(sweep: SweepData, axis: str) -> tuple[np.ndarray, list[str] | None]:
    """Numbers as they are; other values (a rule's name, say) as categories 0, 1, ..."""
    x = sweep.columns[axis]
    if np.all(np.isfinite(x)):
        return x, None
    labels = list(dict.fromkeys(sweep.text[axis]))
    return np.array([labels.index(v) for v in sweep.text[axis]], dtype=float), labels
