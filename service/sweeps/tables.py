"""A sweep folder's tables: runs.csv, table.csv and series.csv, written atomically.

Every CSV has one header row and loads with `pandas.read_csv(path)` (or
`numpy.genfromtxt(path, delimiter=",", names=True)` for the numeric columns) without
options. A missing number (a diverged run's measure, sd with one replica, a run not yet
done) is an empty cell, which both read as NaN. Axis values are written as JSON (numbers,
true/false, objects), strings as they are.

Columns:
  runs.csv    run, point, <axis paths>, replica, seed, status, then each measure's
              columns (Measure.run_columns: <m>, or e.g. <m>, <m>_err, <m>_m2, <m>_m4
              for binder) (status: completed, diverged, or pending for a run not done yet)
  table.csv   point, <axis paths>, then per quantity q of each measure (q = <m>, or
              <m>_m1 ... for moments: Measure.table_quantities) q_mean, q_sd, q_sem,
              [q_err,] q_count (over the replicas with a value; sd is the sample sd,
              sem = sd / sqrt(count); err from the runs' tau_int-based errors; binder and
              susceptibility from the pooled moments, sem by the jackknife: measures.py)
  series.csv  point, <axis paths>, step, time, then per series <obs>_mean, <obs>_sd
              (over the completed replicas of the point, at each observation step)
  sensitivity.csv  with an `analysis`: parameter, its indices, points, points_missing
              (sensitivity.py)
Design paths are axis columns too (after the axes'), their values the design's.
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import math
import os
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any, Literal

import numpy as np

from flocklab.schemas.sweep import REPLICAS_PATH, Measure, Sweep

from .journal import Finished
from .measures import combined_error, pooled_stats, replica_stats
from .run_index import RunIndex

TABLES = ("runs", "table", "series", "sensitivity")
SWEEP_FILE = "sweep.json"


def axis_columns(sweep: Sweep) -> list[str]:
    """The axis paths that become columns (the 'replicas' pseudo-path is not one)."""
    return [a.path for a in sweep.axis_entries() if a.path != REPLICAS_PATH]


def write_tables(out_dir: Path, sweep: Sweep, index: RunIndex, finished: Finished) -> None:
    """(Re)write runs.csv, table.csv and, when the sweep names series, series.csv: one
    pass over the runs in index order (`index`), each finished run's record read back
    from the journal (`finished`), so that only one grid point's records are held."""
    out_dir = Path(out_dir)
    axes = axis_columns(sweep)
    columns = [c for n, m in sweep.measure.items() for c in m.run_columns(n)]
    names = ["runs", "table", *(["series"] if sweep.series else [])]
    with contextlib.ExitStack() as stack:
        # Entered last to first, so that the renames at the end go first to last.
        files = {n: stack.enter_context(atomic_file(out_dir / f"{n}.csv"))
                 for n in reversed(names)}
        journal = stack.enter_context(finished.reader(out_dir))
        runs = csv.writer(files["runs"], lineterminator="\n")
        table = csv.writer(files["table"], lineterminator="\n")
        runs.writerow(["run", "point", *axes, "replica", "seed", "status", *columns])
        table.writerow(["point", *axes, *(f"{q}_{s}" for n, m in sweep.measure.items()
                                          for q, err in m.table_quantities(n)
                                          for s in (("mean", "sd", "sem", "err", "count")
                                                    if err else ("mean", "sd", "sem",
                                                                 "count")))])
        series = None
        if sweep.series:
            series = csv.writer(files["series"], lineterminator="\n")
            series.writerow(["point", *axes, "step", "time",
                             *(f"{o}_{s}" for o in sweep.series for s in ("mean", "sd"))])
        for point in index.points():
            cells = [_axis_cell(point.values[a]) for a in axes]
            done: list[dict[str, Any]] = []  # the point's finished runs' measures
            curves: list[dict[str, Any]] = []  # its completed runs' series
            for i, replica, seed in point.runs:
                rec = journal.get(i)
                measures = rec["measures"] if rec else {}
                runs.writerow(_nums([i, point.point, *cells, replica, seed,
                                     rec["status"] if rec else "pending",
                                     *(measures.get(c) for c in columns)]))
                if rec:
                    done.append(measures)
                    if rec["status"] == "completed":
                        curves.append(rec["series"])
            table.writerow(_nums([point.point, *cells, *(
                x for n, m in sweep.measure.items()
                for x in _point_cells(n, m, done, point.n_agents))]))
            if series is not None and curves:
                series.writerows(_nums(row) for row in
                                 _series_rows(sweep, point.point, cells, curves))


def _series_rows(sweep: Sweep, point: int, cells: list[str],
                 done: list[dict[str, Any]]) -> Iterator[list[Any]]:
    """One grid point's series.csv rows: per observation step the completed replicas'
    mean and sd of each series."""
    # Replicas of one point differ only in the seed: the same observation steps.
    stacks = {o: np.array([d[o] for d in done], dtype=np.float64) for o in sweep.series}
    mean = {o: v.mean(axis=0) for o, v in stacks.items()}
    sd = {o: v.std(axis=0, ddof=1) if len(done) > 1 else None for o, v in stacks.items()}
    for t, (step, time) in enumerate(zip(done[0]["step"], done[0]["time"], strict=True)):
        yield [point, *cells, step, time,
               *(x for o in sweep.series
                 for x in (mean[o][t], None if sd[o] is None else sd[o][t]))]


def _point_cells(name: str, m: Measure, done: list[dict[str, Any]],
                 n_agents: int) -> list[Any]:
    """One grid point's table cells of one measure, quantity by quantity: binder and
    susceptibility from the pooled moments (measures.pooled_stats), every other quantity
    the replicas' mean/sd/sem, and err from the runs' own errors where they carry one."""
    if m.reduce in ("binder", "susceptibility"):
        value, sd, sem, err, count = pooled_stats(m.reduce, done, name, n_agents)
        return [value, sd, sem, err, count]
    cells: list[Any] = []
    for q, has_err in m.table_quantities(name):
        mean, sd, sem, count = replica_stats([d.get(q) for d in done])
        err = [combined_error([d.get(q + "_err") for d in done])] if has_err else []
        cells += [mean, sd, sem, *err, count]
    return cells


def read_table(out_dir: Path, fmt: Literal["csv", "json"] = "csv",
               name: Literal["table", "runs", "series", "sensitivity"] = "table"
               ) -> bytes | dict[str, Any]:
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
    integers = set((sweep.get("design") or {}).get("integer", []))
    reader = csv.reader(io.StringIO(raw.decode()))
    columns = next(reader)
    if name == "sensitivity":
        parse = [str if c == "parameter" else _cell_parser(c, None, c.startswith("points"))
                 for c in columns]
    else:
        parse = [_cell_parser(c, axis_values.get(c), c in integers) for c in columns]
    return {"columns": columns,
            "data": [[f(cell) for f, cell in zip(parse, row, strict=True)] for row in reader]}


def _cell_parser(column: str, values: list[Any] | None, integer: bool = False):
    if values is not None:  # an axis: map the written text back to the sweep's value
        lookup = {_axis_cell(v): v for v in values}
        return lambda cell: lookup.get(cell, cell)
    if column == "status":
        return str
    if integer or column in ("run", "point", "replica", "seed", "step") or column.endswith(
            "_count"):
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


def _nums(row: list[Any]) -> list[str]:
    return [_num(c) for c in row]


def csv_text(header: list[str], rows: list[list[Any]]) -> str:
    """One header row, then the rows (cells as _num writes them: empty for None/NaN)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)
    w.writerows(_nums(row) for row in rows)
    return buf.getvalue()


def atomic_write(path: Path, text: str, *, durable: bool = True) -> None:
    """Write `text` to `path` through a temporary sibling and a rename, so a reader or a
    crash never sees a half-written file; `durable` fsyncs it before the rename."""
    with atomic_file(path, durable=durable) as fh:
        fh.write(text)


@contextlib.contextmanager
def atomic_file(path: Path, *, durable: bool = True) -> Iterator[IO[str]]:
    """A text file to write `path` through: a temporary sibling, renamed to `path` when
    the block ends (fsynced first when `durable`), removed if it raises."""
    tmp = path.with_name(f".{path.name}.tmp-{uuid.uuid4().hex[:8]}")
    try:
        with open(tmp, "w") as fh:
            yield fh
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
    try:
        sweep = Sweep.model_validate(json.loads((Path(out_dir) / SWEEP_FILE).read_text())
                                     ["sweep"])
    except (OSError, ValueError, KeyError, TypeError):
        return False  # no sweep.json yet: the attempt died before its first run
    index = RunIndex.build(sweep)
    finished = Finished.from_journal(out_dir, index.n_runs)
    if not finished.count:
        return False
    write_tables(Path(out_dir), sweep, index, finished)
    return True
