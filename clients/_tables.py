"""A sweep's tables on the client side: their routes and their decoding (JSON to a numpy
structured array, or a pandas DataFrame)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    import pandas

TABLES = ("table", "runs", "series", "sensitivity")


def table_path(sweep_id: str, name: str) -> str:
    if name not in TABLES:
        raise ValueError(f"not a sweep table: {name!r}; one of {', '.join(TABLES)}")
    return f"/v1/sweeps/{sweep_id}/{name}"


def structured(body: dict[str, Any]) -> np.ndarray:
    """The JSON form of a CSV table as a numpy structured array, one field per column.

    A column of integers stays int64 (float64 with NaN when a cell is empty), numbers are
    float64 (null as NaN), true/false bool, text a unicode string column; an axis whose
    values are JSON objects or lists is an object column.
    """
    columns: list[str] = body["columns"]
    rows: list[list[Any]] = body["data"]
    values = [[r[i] for r in rows] for i in range(len(columns))]
    arrays = [_column(v) for v in values]
    out = np.empty(len(rows), dtype=[(c, a.dtype) for c, a in zip(columns, arrays, strict=True)])
    for c, a in zip(columns, arrays, strict=True):
        out[c] = a
    return out


def _column(values: list[Any]) -> np.ndarray:
    present = [v for v in values if v is not None]
    if any(isinstance(v, dict | list) for v in present):
        out = np.empty(len(values), dtype=object)
        out[:] = values
        return out
    if present and len(present) == len(values) and all(isinstance(v, bool) for v in present):
        return np.array(values, dtype=bool)
    if any(isinstance(v, str) for v in present):
        return np.array(["" if v is None else str(v) for v in values], dtype=str)
    if present and len(present) == len(values) and all(
            isinstance(v, int) and not isinstance(v, bool) for v in present):
        return np.array(values, dtype=np.int64)
    return np.array([np.nan if v is None else v for v in values], dtype=np.float64)


def frame(table: np.ndarray) -> pandas.DataFrame:
    """A pandas DataFrame of a structured array (pandas is optional: a clear ImportError)."""
    try:
        import pandas
    except ImportError:
        raise ImportError("table_frame() needs pandas (pip install pandas); table() gives "
                          "the same data as a numpy structured array") from None
    return pandas.DataFrame(table)
