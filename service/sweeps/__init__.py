"""Sweeps: many runs of one scenario over a parameter grid, reduced into tables.

`run_sweep` (runner.py) runs a `schemas.sweep.Sweep` into a folder, resumably;
`read_table` (tables.py) serves its tables. Importing this package never imports the
engine (only `run_sweep` does, when it runs).
"""

from .runner import SweepFolderConflict, SweepOutcome, SweepProgress, run_sweep
from .tables import read_table

__all__ = ["SweepFolderConflict", "SweepOutcome", "SweepProgress", "read_table", "run_sweep"]
