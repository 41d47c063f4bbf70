"""A sweep's CSV tables (table.csv, runs.csv, series.csv) as JSON.

Read here rather than through the sweep runner's helpers, which live next to the engine:
the API process must never import Taichi. Each cell becomes an int, a float or a string
as it reads; an empty cell and NaN/±Inf (which JSON cannot hold) become null.
"""

from __future__ import annotations

import csv
import math
import re
from pathlib import Path
from typing import Any

_INT = re.compile(r"^[+-]?\d+$")


def csv_as_json(path: Path) -> dict[str, Any]:
    """{"columns": [header...], "rows": [[cell...], ...]}, the CSV's row order kept."""
    with path.open(newline="") as f:
        rows = list(csv.reader(f))
    if not rows:
        return {"columns": [], "rows": []}
    return {"columns": rows[0], "rows": [[_cell(c) for c in r] for r in rows[1:]]}


def _cell(text: str) -> int | float | str | None:
    if text == "":
        return None
    if _INT.match(text):
        return int(text)
    try:
        value = float(text)
    except ValueError:
        return text
    return value if math.isfinite(value) else None
