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
from array import array
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

JOURNAL = "runs.jsonl"
FSYNC_INTERVAL = 1.0  # seconds


def scan_journal(out_dir: Path) -> Iterator[tuple[int, dict[str, Any]]]:
    """(byte offset of its line, record) for each record of `out_dir`'s journal, in file
    order, one at a time (a run redone has a later line too)."""
    path = Path(out_dir) / JOURNAL
    if not path.exists():
        return
    offset = 0
    with open(path, "rb") as fh:
        for line in fh:
            at, offset = offset, offset + len(line)
            try:
                rec = json.loads(line)
            except ValueError:
                continue  # the tail of a line cut short by a crash
            if isinstance(rec, dict) and isinstance(rec.get("run"), int):
                yield at, rec


def read_journal(out_dir: Path) -> dict[int, dict[str, Any]]:
    """The finished runs recorded in `out_dir` (run index -> record); a later line for
    the same run wins. (Holds every record: the runner keeps `Finished` instead.)"""
    return {rec["run"]: rec for _, rec in scan_journal(out_dir)}


class Finished:
    """The finished runs of a sweep of `n_runs` runs, in O(1) memory per run: where each
    one's journal line starts (-1: not finished) and whether it completed; the records
    themselves are read back from the journal when the tables are written."""

    def __init__(self, n_runs: int):
        self.n_runs = n_runs
        self.offsets = array("q", [-1]) * n_runs
        self.completed = bytearray(n_runs)
        self.count = 0  # finished runs
        self.failed = 0  # finished runs that did not complete (diverged)

    @classmethod
    def from_journal(cls, out_dir: Path, n_runs: int) -> Finished:
        """The runs `out_dir`'s journal records (a later line for a run wins; indexes
        outside the sweep are ignored)."""
        done = cls(n_runs)
        for offset, rec in scan_journal(out_dir):
            if 0 <= rec["run"] < n_runs:
                done.add(rec["run"], offset, rec.get("status") == "completed")
        return done

    def __contains__(self, index: int) -> bool:
        return self.offsets[index] >= 0

    def add(self, index: int, offset: int, completed: bool) -> None:
        """Run `index` finished, its record at `offset` (replacing an earlier one)."""
        if self.offsets[index] < 0:
            self.count += 1
        else:
            self.failed -= not self.completed[index]
        self.offsets[index] = offset
        self.completed[index] = completed
        self.failed += not completed

    def reader(self, out_dir: Path) -> JournalReader:
        return JournalReader(out_dir, self)


class JournalReader:
    """Reads finished runs' records back from the journal, by run index (a context)."""

    def __init__(self, out_dir: Path, finished: Finished):
        self.finished = finished
        path = Path(out_dir) / JOURNAL
        self.fh: IO[bytes] | None = open(path, "rb") if finished.count else None  # noqa: SIM115

    def __enter__(self) -> JournalReader:
        return self

    def __exit__(self, *exc: object) -> None:
        if self.fh is not None:
            self.fh.close()

    def get(self, index: int) -> dict[str, Any] | None:
        """Run `index`'s record, or None while it is not finished."""
        offset = self.finished.offsets[index]
        if offset < 0 or self.fh is None:
            return None
        self.fh.seek(offset)
        return json.loads(self.fh.readline())


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
        self.fh = open(path, "ab")  # noqa: SIM115  (held open for the whole sweep)
        if torn:
            self.fh.write(b"\n")
        self.offset = self.fh.tell()  # where the next line starts
        self.last_sync = time.monotonic()

    def append(self, record: dict[str, Any]) -> int:
        """Append `record`'s line; returns the offset where it starts."""
        line = (json.dumps(record, allow_nan=False, separators=(",", ":")) + "\n").encode()
        at = self.offset
        self.fh.write(line)
        self.fh.flush()
        self.offset += len(line)
        if time.monotonic() - self.last_sync >= FSYNC_INTERVAL:
            os.fsync(self.fh.fileno())
            self.last_sync = time.monotonic()
        return at

    def close(self) -> None:
        self.fh.flush()
        os.fsync(self.fh.fileno())
        self.fh.close()
