"""A design sweep's sensitivity analysis: sensitivity.csv, with SALib.

The model output Y is the analysed quantity's table.csv mean over replicas (column
`<measure>_mean`), one value per design point in point order; the inputs are the design's
points in the unit cube (schemas/sweep_design.py), so every index is per the parameter's
whole range (its log range for a `log` path), comparable across parameters.

  sobol   SALib.analyze.sobol.analyze(calc_second_order=False): per parameter S1 (first
          order), S1_conf, ST (total), ST_conf; the conf columns are half-widths of the
          bootstrap interval at `conf_level` (Saltelli et al., Comput. Phys. Commun. 181,
          259 (2010) for the estimators SALib implements).
  morris  SALib.analyze.morris.analyze(num_levels=levels): per parameter mu (mean
          elementary effect), mu_star (mean of |effect|, Campolongo et al. 2007), sigma
          (their sd) and mu_star_conf (bootstrap half-width).

A point without a value (its runs diverged) leaves the output undefined: the file is then
written with empty cells and `points_missing` > 0 on each row.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from flocklab.schemas.sweep import Sweep
from flocklab.schemas.sweep_design import Analysis, Design

from .tables import atomic_write, csv_text, read_table

SENSITIVITY_FILE = "sensitivity.csv"
COLUMNS = {"sobol": ("S1", "S1_conf", "ST", "ST_conf"),
           "morris": ("mu", "mu_star", "sigma", "mu_star_conf")}


def write_sensitivity(out_dir: Path, sweep: Sweep) -> None:
    """sensitivity.csv of a sweep with an analysis, from its written table.csv:
    `parameter, <the kind's columns>, points, points_missing`."""
    analysis, design = sweep.analysis, sweep.design
    assert analysis is not None and design is not None
    table = read_table(Path(out_dir), "json")
    assert isinstance(table, dict)
    col = table["columns"].index(f"{analysis.measure}_mean")
    y = np.array([math.nan if row[col] is None else row[col] for row in table["data"]],
                 dtype=np.float64)
    names = list(design.bounds)
    missing = int(np.count_nonzero(~np.isfinite(y)))
    values = [[None] * len(COLUMNS[analysis.kind]) for _ in names]
    if missing == 0:
        values = analyse(design, analysis, y)
    rows = [[name, *v, len(y), missing] for name, v in zip(names, values, strict=True)]
    atomic_write(Path(out_dir) / SENSITIVITY_FILE,
                 csv_text(["parameter", *COLUMNS[analysis.kind], "points", "points_missing"],
                      rows))


def analyse(design: Design, analysis: Analysis, y: np.ndarray) -> list[list[float]]:
    """SALib's indices (the kind's COLUMNS) per parameter, in `bounds` order, of the
    outputs y at the design's points (in point order)."""
    d = len(design.bounds)
    problem = {"num_vars": d, "names": list(design.bounds), "bounds": [[0.0, 1.0]] * d}
    if analysis.kind == "sobol":
        from SALib.analyze import sobol

        r = sobol.analyze(problem, y, calc_second_order=False,
                          num_resamples=analysis.resamples, conf_level=analysis.conf_level,
                          seed=analysis.seed)
    else:
        from SALib.analyze import morris

        r = morris.analyze(problem, design.unit_points("morris"), y,
                           num_resamples=analysis.resamples, conf_level=analysis.conf_level,
                           num_levels=design.levels, seed=analysis.seed)
    return [[float(r[c][i]) for c in COLUMNS[analysis.kind]] for i in range(d)]
