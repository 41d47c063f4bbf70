"""A running run's observation rows on disk, for readers outside the run (the API).

`execute_to_dir` hands `LiveObservables.append` to the engine as its `on_observations`:
each batch of rows is appended to `observables.partial.csv` in the run's hidden folder,
in the final `observables.csv`'s format (the same header, `%.17g`, so a value reads back
to the same float). A reader never sees half a row: the file appears by rename with its
header and first rows, every later batch is one `write` of whole lines, and
`complete_rows` stops at the last newline (a batch may be read while it lands). The file
is deleted once the final `observables.csv` is written, before the folder is moved into
place, so finished results never hold it.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterator
from pathlib import Path

import numpy as np

LIVE_FILE = "observables.partial.csv"
log = logging.getLogger("flocklab.live")


def csv_lines(rows: dict[str, np.ndarray], names: list[str]) -> str:
    """The rows as CSV lines, each ending in a newline (observables.csv's number format)."""
    table = np.column_stack([rows[k] for k in names])
    return "".join(",".join(f"{v:.17g}" for v in row) + "\n" for row in table.tolist())


class LiveObservables:
    """Appends observation rows to `path` as they arrive (see the module docstring)."""

    def __init__(self, path: Path):
        self.path = Path(path)
        self.names: list[str] | None = None
        self.stopped = False

    def append(self, rows: dict[str, np.ndarray]) -> None:
        """Publish `rows` (the engine's `on_observations`). Publishing is best effort: a
        write that fails (a full disk) stops it, and the run goes on to write its final
        results, which report the failure if the disk is still full."""
        if self.stopped:
            return
        try:
            if self.names is None:
                names = list(rows)
                tmp = self.path.with_name(f".{self.path.name}.tmp")
                tmp.write_text(",".join(names) + "\n" + csv_lines(rows, names))
                os.replace(tmp, self.path)
                self.names = names
            else:
                text = csv_lines(rows, self.names)
                with self.path.open("a") as f:
                    f.write(text)
        except OSError as exc:
            log.warning("live observables stopped: %s", exc)
            self.stopped = True

    def remove(self) -> None:
        """Delete the file (the final observables.csv supersedes it)."""
        self.path.unlink(missing_ok=True)
        self.path.with_name(f".{self.path.name}.tmp").unlink(missing_ok=True)


def complete_rows(path: Path, start: int = 0, limit: int | None = None
                  ) -> tuple[list[str], Iterator[list[str]]]:
    """The header of a CSV that may be growing, and an iterator over its complete rows
    (split into cells) from row `start` on, at most `limit` of them; a last line without
    its newline (being written) is left out. Raises OSError when the file is missing."""
    f = path.open(newline="", errors="replace")
    header = f.readline()
    if not header.endswith("\n"):
        f.close()
        return [], iter(())
    names = header.rstrip("\r\n").split(",")

    def rows() -> Iterator[list[str]]:
        with f:
            taken = 0
            for i, line in enumerate(f):
                if not line.endswith("\n"):
                    return
                if i < start:
                    continue
                if limit is not None and taken >= limit:
                    return
                taken += 1
                yield line.rstrip("\r\n").split(",")

    return names, rows()
