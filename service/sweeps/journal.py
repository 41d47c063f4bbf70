"""runs.jsonl: the sweep's journal, one JSON line per finished run (the resume state).

A line is appended and flushed as each run finishes, so a crash or kill of the process
loses at most the runs in progress; it is fsynced at most every FSYNC_INTERVAL seconds
and at the end (an fsync costs ~5 ms, a small run not much more), so an operating-system
crash or power loss loses at most that much more. A line cut short by a crash is ignored
on reading (that run is simply redone).
Each record: {"run", "status" ("completed" | "diverged"), "seed", "measures": {name:
value or null}, "series": {"step": [...], "time": [...], <obs>: [...]} (the observables
named in the sweep's `series`; empty otherwise), "error": the divergence or null}.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path
from typing import Any

JOURNAL = "runs.jsonl"
FSYNC_INTERVAL = 1.0  # seconds


def read_journal(out_dir: Path) -> dict[int, dict[str, Any]]:
    """The finished runs recorded in `out_dir` (run index -> record); a later line for
    the same run wins."""
    path = Path(out_dir) / JOURNAL
    records: dict[int, dict[str, Any]] = {}
    if not path.exists():
        return records
    with open(path) as fh:
        for line in fh:
            try:
                rec = json.loads(line)
            except ValueError:
                continue  # the tail of a line cut short by a crash
            if isinstance(rec, dict) and isinstance(rec.get("run"), int):
                records[rec["run"]] = rec
    return records


class Journal:
    """Appends records to runs.jsonl (flushed per line, fsynced every FSYNC_INTERVAL)."""

    def __init__(self, out_dir: Path):
        path = Path(out_dir) / JOURNAL
        # A crash may have left a partial last line; start ours on a fresh one.
        torn = False
        if path.exists() and path.stat().st_size:
            with open(path, "rb") as fh:
                fh.seek(-1, os.SEEK_END)
                torn = fh.read(1) != b"\n"
        self.fh = open(path, "a")  # noqa: SIM115  (held open for the whole sweep)
        if torn:
            self.fh.write("\n")
        self.last_sync = time.monotonic()

    def append(self, record: dict[str, Any]) -> None:
        self.fh.write(json.dumps(record, allow_nan=False, separators=(",", ":")) + "\n")
        self.fh.flush()
        if time.monotonic() - self.last_sync >= FSYNC_INTERVAL:
            os.fsync(self.fh.fileno())
            self.last_sync = time.monotonic()

    def close(self) -> None:
        self.fh.flush()
        os.fsync(self.fh.fileno())
        self.fh.close()
