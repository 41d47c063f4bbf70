"""Disk space: the free-space reserve, recognising a full disk, and keeping server paths
out of what clients see.

Both processes import this (the API checks the reserve before accepting a body, the
supervisor before starting a job, the worker maps a full disk to a problem), so it is
plain Python.
"""

from __future__ import annotations

import errno
import os
import re
import sqlite3
from pathlib import Path
from typing import Any

from .problems import problem

# Messages a full disk produces where no errno survives: h5py wraps HDF5's error stack in
# an OSError of its own, and SQLite reports SQLITE_FULL as an OperationalError.
_FULL_MESSAGES = ("no space left on device", "database or disk is full", "disk quota exceeded",
                  "errno = 28")
# Absolute POSIX paths (two or more components) inside an error message.
_PATH = re.compile(r"(?<![\w.])/(?:[^\s'\"/:,;()]+/)+[^\s'\"/:,;()]*")


def free_bytes(path: Path) -> int:
    """Bytes an unprivileged writer may still use on the filesystem holding `path`."""
    st = os.statvfs(path)
    return st.f_bavail * st.f_frsize


def is_disk_full(exc: BaseException) -> bool:
    """Whether `exc` (or an exception it was raised from) means the disk is full."""
    seen: set[int] = set()
    e: BaseException | None = exc
    while e is not None and id(e) not in seen:
        seen.add(id(e))
        if isinstance(e, OSError) and e.errno in (errno.ENOSPC, errno.EDQUOT):
            return True
        if isinstance(e, OSError | sqlite3.OperationalError | RuntimeError):
            text = str(e).lower()
            if any(m in text for m in _FULL_MESSAGES):
                return True
        e = e.__cause__ or e.__context__
    return False


def scrub_paths(text: str) -> str:
    """`text` with every absolute path replaced by `<path>` (never show server paths)."""
    return _PATH.sub("<path>", text)


def disk_full_problem(where: str) -> dict[str, Any]:
    """The problem body for a job (or request) that ran out of disk space."""
    return problem("insufficient-storage", "Out of disk space", 507,
                   f"the server's data disk is full ({where}); free space or raise the "
                   f"quota, then submit the job again")
