"""What the sync and async sweep handles share: the request body, the table decoding and
the state checks."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from flocklab.schemas.status import SweepStatus
from flocklab.schemas.sweep import Sweep

from .errors import FlocklabError

if TYPE_CHECKING:
    import pandas

TABLES = ("table", "runs", "series", "sensitivity")


class SweepFailed(FlocklabError):
    """`wait()` found the sweep ended without succeeding (failed, timed out, cancelled).
    `status` is its final `SweepStatus`; the runs finished before the end may still be
    fetched with `table()`."""

    def __init__(self, status: SweepStatus):
        self.status = status
        why = f": {status.error.detail}" if status.error and status.error.detail else ""
        super().__init__(f"sweep {status.id} {status.status} after {status.runs_done} of "
                         f"{status.runs_total} runs{why}")


def submission(spec: Sweep | dict[str, Any] | None, sweep_preset: str | None,
               timeout_seconds: float | None) -> dict[str, Any]:
    """The POST /v1/sweeps body: the bare sweep, or wrapped (a named sweep, a timeout)."""
    if (spec is None) == (sweep_preset is None):
        raise ValueError("give exactly one of a sweep and sweep_preset=")
    if sweep_preset is not None:
        body: dict[str, Any] = {"sweep_preset": sweep_preset}
    else:
        sweep = spec.model_dump(mode="json") if isinstance(spec, Sweep) else spec
        if not isinstance(sweep, dict):
            raise TypeError("a sweep is a schemas.sweep.Sweep or a dict")
        if timeout_seconds is None:
            return sweep
        body = {"sweep": sweep}
    if timeout_seconds is not None:
        body["timeout_seconds"] = timeout_seconds
    return body


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
