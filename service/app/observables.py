"""A job's observables series (observables.csv) as streamed JSON.

A long run observed every step has millions of rows: the metrics body is written a
column at a time, reading the CSV once per column in blocks of rows, so the server holds
one block, never the whole series (`{"observables": {"step": [...], "time": [...], ...}}`
keeps the shape clients already read). `read_rows` pages through a running job's rows
(the live file, see service/live_observables.py) or a finished job's CSV.
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from flocklab.service.jobs import Job
from flocklab.service.jobs.results import ResultStore
from flocklab.service.live_observables import LIVE_FILE, complete_rows

ROWS_PER_CHUNK = 8192


class CorruptObservables(ValueError):
    """The CSV has no readable header."""


def read_header(path: Path) -> list[str]:
    """The column names (raises OSError when the file is missing, CorruptObservables when
    it is not a CSV with a header)."""
    with path.open(newline="") as f:
        try:
            header = next(csv.reader(f), None)
        except (csv.Error, UnicodeDecodeError) as exc:
            raise CorruptObservables(str(exc)) from None
    if header is None:
        return []
    if not all(name.strip() for name in header):
        raise CorruptObservables("empty column name in the header")
    return header


def _number(s: str) -> float | None:
    try:
        v = float(s)
    except ValueError:
        return None
    return v if math.isfinite(v) else None


def _column(path: Path, index: int) -> Iterator[str]:
    """One column as JSON text, in chunks; unreadable cells are null."""
    with path.open(newline="", errors="replace") as f:
        rows = csv.reader(f)
        next(rows, None)
        chunk: list[float | None] = []
        first = True
        for row in rows:
            chunk.append(_number(row[index]) if index < len(row) else None)
            if len(chunk) >= ROWS_PER_CHUNK:
                yield ("" if first else ",") + json.dumps(chunk)[1:-1]
                first, chunk = False, []
        if chunk:
            yield ("" if first else ",") + json.dumps(chunk)[1:-1]


def stream_metrics(head: dict[str, Any], path: Path, names: list[str]) -> Iterator[bytes]:
    """`head` (job id, summary) with `"observables"` streamed in from the CSV."""
    opening = json.dumps(head)[:-1]
    yield f'{opening}, "observables": {{'.encode()
    for i, name in enumerate(names):
        yield f'{", " if i else ""}{json.dumps(name)}: ['.encode()
        for part in _column(path, i):
            yield part.encode()
        yield b"]"
    yield b"}}"


def live_sources(results: ResultStore, job: Job) -> list[Path]:
    """Where a running job's rows are, newest writer first: the live file in its
    attempt's hidden folder while the run goes on, then the attempt's final
    observables.csv (the run has ended, the service has not committed it yet)."""
    if job.lease_token is None:
        return []
    attempt = results.attempt_dir(job.id, job.lease_token)
    return [*attempt.parent.glob(f".{attempt.name}.partial-*/{LIVE_FILE}"),
            attempt / "observables.csv"]


def read_rows(path: Path, start: int, limit: int) -> tuple[dict[str, list[float | None]], bool]:
    """Rows `start` .. `start + limit` of a (possibly growing) observables CSV as columns,
    non-finite or unreadable cells as null; and whether more rows follow. Raises OSError
    when the file is missing, CorruptObservables when its header is unreadable."""
    names, rows = complete_rows(path, start, limit + 1)
    if not all(name.strip() for name in names):
        raise CorruptObservables("empty column name in the header")
    columns: dict[str, list[float | None]] = {name: [] for name in names}
    lists = list(columns.values())
    more = False
    for i, row in enumerate(rows):
        if i == limit:
            more = True
            break
        for j, col in enumerate(lists):
            col.append(_number(row[j]) if j < len(row) else None)
    return columns, more
