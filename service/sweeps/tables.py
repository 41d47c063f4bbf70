"""A sweep folder's tables: runs.csv, table.csv and series.csv, written atomically.

Every CSV has one header row and loads with `pandas.read_csv(path)` (or
`numpy.genfromtxt(path, delimiter=",", names=True)` for the numeric columns) without
options. A missing number (a diverged run's measure, sd with one replica, a run not yet
done) is an empty cell, which both read as NaN. Axis values are written as JSON (numbers,
true/false, objects), strings as they are.

Columns:
  runs.csv    run, point, <axis paths>, replica, seed, status, <measures>
              (status: completed, diverged, or pending for a run not done yet)
  table.csv   point, <axis paths>, then per measure <m>_mean, <m>_sd, <m>_sem, <m>_count
              (over the replicas with a value; sd is the sample sd, sem = sd / sqrt(count))
  series.csv  point, <axis paths>, step, time, then per series <obs>_mean, <obs>_sd
              (over the completed replicas of the point, at each observation step)
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import uuid
from pathlib import Path
from typing import Any, Literal

import numpy as np

from flocklab.schemas.sweep import REPLICAS_PATH, Sweep, SweepRun

from .measures import replica_stats

TABLES = ("runs", "table", "series")
SWEEP_FILE = "sweep.json"


def axis_columns(sweep: Sweep) -> list[str]:
    """The axis paths that become columns (the 'replicas' pseudo-path is not one)."""
    return [a.path for a in sweep.axis_entries() if a.path != REPLICAS_PATH]


def write_tables(out_dir: Path, sweep: Sweep, runs: list[SweepRun],
                 records: dict[int, dict[str, Any]]) -> None:
    """(Re)write runs.csv, table.csv and, when the sweep names series, series.csv from the
    finished runs' records (index -> record, see runner.py)."""
    axes = axis_columns(sweep)
    names = list(sweep.measure)
    rows = []
    for r in runs:
        rec = records.get(r.index)
        measures = rec["measures"] if rec else {}
        rows.append([r.index, r.point, *(_axis_cell(r.values[a]) for a in axes), r.replica,
                     r.seed, rec["status"] if rec else "pending",
                     *(measures.get(n) for n in names)])
    atomic_write(out_dir / "runs.csv",
                 _csv(["run", "point", *axes, "replica", "seed", "status", *names], rows))

    points: dict[int, list[SweepRun]] = {}
    for r in runs:
        points.setdefault(r.point, []).append(r)
    header = ["point", *axes, *(f"{n}_{s}" for n in names for s in ("mean", "sd", "sem",
                                                                       "count"))]
    rows = []
    for p, members in points.items():
        done = [records[r.index] for r in members if r.index in records]
        stats = [replica_stats([rec["measures"].get(n) for rec in done]) for n in names]
        rows.append([p, *(_axis_cell(members[0].values[a]) for a in axes),
                     *(x for s in stats for x in s)])
    atomic_write(out_dir / "table.csv", _csv(header, rows))

    if sweep.series:
        atomic_write(out_dir / "series.csv", _series_csv(sweep, axes, points, records))


def _series_csv(sweep: Sweep, axes: list[str], points: dict[int, list[SweepRun]],
                records: dict[int, dict[str, Any]]) -> str:
    header = ["point", *axes, "step", "time",
              *(f"{o}_{s}" for o in sweep.series for s in ("mean", "sd"))]
    rows = []
    for p, members in points.items():
        done = [records[r.index]["series"] for r in members
                if records.get(r.index, {}).get("status") == "completed"]
        if not done:
            continue
        # Replicas of one point differ only in the seed: the same observation steps.
        stacks = {o: np.array([d[o] for d in done], dtype=np.float64) for o in sweep.series}
        mean = {o: v.mean(axis=0) for o, v in stacks.items()}
        sd = {o: v.std(axis=0, ddof=1) if len(done) > 1 else None for o, v in stacks.items()}
        cells = [_axis_cell(members[0].values[a]) for a in axes]
        for t, (step, time) in enumerate(zip(done[0]["step"], done[0]["time"], strict=True)):
            rows.append([p, *cells, step, time,
                         *(x for o in sweep.series
                           for x in (mean[o][t], None if sd[o] is None else sd[o][t]))])
    return _csv(header, rows)


def read_table(out_dir: Path, fmt: Literal["csv", "json"] = "csv",
               name: Literal["table", "runs", "series"] = "table") -> bytes | dict[str, Any]:
    """A table of a sweep folder: the CSV bytes, or {"columns": [...], "data": [[...]]}
    with typed cells (numbers, axis values as in the sweep file, null for empty cells;
    `pandas.DataFrame(**obj)` builds the frame). FileNotFoundError before it is written."""
    if name not in TABLES:
        raise ValueError(f"unknown table {name!r}; known: {', '.join(TABLES)}")
    raw = (Path(out_dir) / f"{name}.csv").read_bytes()
    if fmt == "csv":
        return raw
    if fmt != "json":
        raise ValueError(f"unknown format {fmt!r}; known: csv, json")
    sweep = json.loads((Path(out_dir) / SWEEP_FILE).read_text())["sweep"]
    axis_values = {a["path"]: a["values"] for ax in sweep["axes"]
                   for a in ax.get("zip", [ax])}
    reader = csv.reader(io.StringIO(raw.decode()))
    columns = next(reader)
    parse = [_cell_parser(c, axis_values.get(c)) for c in columns]
    return {"columns": columns,
            "data": [[f(cell) for f, cell in zip(parse, row, strict=True)] for row in reader]}


def _cell_parser(column: str, values: list[Any] | None):
    if values is not None:  # an axis: map the written text back to the sweep's value
        lookup = {_axis_cell(v): v for v in values}
        return lambda cell: lookup.get(cell, cell)
    if column == "status":
        return str
    if column in ("run", "point", "replica", "seed", "step") or column.endswith("_count"):
        return lambda cell: int(cell) if cell else None
    return lambda cell: float(cell) if cell else None


def _axis_cell(value: Any) -> str:
    return value if isinstance(value, str) else json.dumps(value, separators=(",", ":"))


def _num(value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, str):
        return value
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool):
        return str(int(value))
    v = float(value)
    return repr(v) if math.isfinite(v) else ""


def _csv(header: list[str], rows: list[list[Any]]) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)
    w.writerows([_num(c) for c in row] for row in rows)
    return buf.getvalue()


def atomic_write(path: Path, text: str, *, durable: bool = True) -> None:
    """Write `text` to `path` through a temporary sibling and a rename, so a reader or a
    crash never sees a half-written file; `durable` fsyncs it before the rename."""
    tmp = path.with_name(f".{path.name}.tmp-{uuid.uuid4().hex[:8]}")
    try:
        with open(tmp, "w") as fh:
            fh.write(text)
            fh.flush()
            if durable:
                os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def rebuild_tables(out_dir: Path) -> bool:
    """Rewrite the tables of a sweep folder from its sweep.json and journal (runs.jsonl,
    each finished run once); False when it holds no finished run. For a sweep whose
    worker died before it could write them: the finished runs are kept, not thrown away."""
    from .journal import read_journal

    try:
        sweep = Sweep.model_validate(json.loads((Path(out_dir) / SWEEP_FILE).read_text())
                                     ["sweep"])
    except (OSError, ValueError, KeyError, TypeError):
        return False  # no sweep.json yet: the attempt died before its first run
    runs = sweep.expand()
    records = {i: r for i, r in read_journal(out_dir).items() if i < len(runs)}
    if not records:
        return False
    write_tables(Path(out_dir), sweep, runs, records)
    return True
