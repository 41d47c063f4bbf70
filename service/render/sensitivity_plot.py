"""A design sweep's pictures: sensitivity.csv as bars (Sobol' S1 and ST, or Morris mu*
and sigma, with their confidence half-widths), and, without an analysis, each measure
against each design parameter as a scatter."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from .errors import RenderInputError
from .figure import check_size
from .run_data import SweepData, read_csv_columns

SENSITIVITY_FILE = "sensitivity.csv"
MAX_PANELS = 6  # design parameters drawn side by side (the first ones)


def has_sensitivity(folder: Path) -> bool:
    return (Path(folder) / SENSITIVITY_FILE).is_file()


def draw_sensitivity(fig: Any, sweep: SweepData, width: int, height: int) -> str:
    """Bars per parameter; returns the analysis kind ('sobol' or 'morris')."""
    check_size(width, height)
    text, cols = read_csv_columns(sweep.folder / SENSITIVITY_FILE)
    if "S1" in cols:
        kind, bars = "sobol", (("S1", "S1_conf", "first order S₁"),
                               ("ST", "ST_conf", "total S_T"))
    elif "mu_star" in cols:
        kind, bars = "morris", (("mu_star", "mu_star_conf", "μ*"), ("sigma", None, "σ"))
    else:
        raise RenderInputError(f"{sweep.folder}/{SENSITIVITY_FILE}: neither Sobol' nor "
                               "Morris columns")
    names = [sweep.label(p) for p in text.get("parameter", [])]
    ax = fig.subplots(1, 1)
    x = np.arange(len(names))
    width_bar = 0.38
    for k, (col, conf, label) in enumerate(bars):
        err = np.nan_to_num(cols[conf]) if conf else None
        ax.bar(x + (k - 0.5) * width_bar, cols[col], width_bar, yerr=err, capsize=3,
               label=label)
    ax.set_xticks(x, names)
    ax.axhline(0, c="k", lw=0.6)
    ax.grid(alpha=0.3, axis="y")
    ax.legend(fontsize=8)
    measure = (sweep.spec.get("sweep") or {}).get("analysis", {}).get("measure", "")
    what = "Sobol' indices" if kind == "sobol" else "Morris elementary effects"
    fig.suptitle(f"{sweep.name}: {what} of {sweep.label(measure)}", fontsize=10)
    fig.tight_layout()
    return kind


def draw_design(fig: Any, sweep: SweepData, measures: list[str], width: int,
                height: int) -> list[str]:
    """Each measure (rows) against each design parameter (columns, the first
    MAX_PANELS): one marker per design point, error bars from the replicas' sem."""
    check_size(width, height)
    design = (sweep.spec.get("sweep") or {}).get("design") or {}
    params = [p for p in design.get("bounds", {}) if p in sweep.columns][:MAX_PANELS]
    if not params:
        raise RenderInputError(f"{sweep.folder}: the design's parameters are not in "
                               "table.csv")
    axes = fig.subplots(len(measures), len(params), squeeze=False, sharey="row")
    for i, m in enumerate(measures):
        y = sweep.columns[f"{m}_mean"]
        err = sweep.columns.get(f"{m}_sem")
        for j, p in enumerate(params):
            ax = axes[i, j]
            ax.errorbar(sweep.columns[p], y, yerr=None if err is None else np.nan_to_num(err),
                        fmt="o", ms=3, capsize=2, lw=0.8)
            if p in design.get("log", []):
                ax.set_xscale("log")
            ax.grid(alpha=0.3)
            if j == 0:
                ax.set_ylabel(sweep.label(m))
            if i == len(measures) - 1:
                ax.set_xlabel(sweep.label(p))
    fig.suptitle(f"{sweep.name}: {design.get('kind', '')} design, "
                 f"{len(sweep.columns[params[0]])} points", fontsize=10)
    fig.tight_layout()
    return measures
