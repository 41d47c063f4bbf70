"""The render cache's bounds: its size, and the data disk's free-space reserve.

Every picture drawn for a GET is kept under its results folder (`<results>/<id>/render/`)
so that asking again is a file read; without a bound, GETs with ever new options (sizes,
frames) filled the disk, past the reserve that submissions respect. `RenderCache` keeps

- the cached files' total size at most `max_bytes`: after each new file, the least
  recently used ones (by modification time; a hit touches its file) are deleted until the
  total fits (the newest is kept even when it alone is larger);
- the reserve: before a draw, below `min_free_bytes` free on the data disk, cached files
  are deleted (least recently used first) until the disk is back above it; if that is not
  enough the draw is refused with 503 `insufficient-storage` and a Retry-After.

The index is built on first use from one scan of the results folders and kept in memory
in LRU order; files deleted under it (results expiring) are dropped when reached. Thread-
safe: the routes call it from the thread pool.
"""

from __future__ import annotations

import os
import threading
from collections import OrderedDict
from pathlib import Path

from flocklab.service.jobs.disk import free_bytes

from .problems import ProblemError

RENDER_DIR = "render"
DISK_RETRY_AFTER = 60


class RenderCache:
    def __init__(self, results_root: Path, max_bytes: int, min_free_bytes: int):
        self.root = results_root
        self.max_bytes = max_bytes
        self.min_free_bytes = min_free_bytes
        self._lock = threading.Lock()
        self._files: OrderedDict[Path, int] | None = None  # path -> size, oldest first
        self._total = 0

    @property
    def total_bytes(self) -> int:
        with self._lock:
            self._load()
            return self._total

    def _load(self) -> None:
        if self._files is not None:
            return
        found: list[tuple[float, Path, int]] = []
        for path in self.root.glob(f"*/{RENDER_DIR}/*"):
            if path.name.startswith("."):
                continue  # a draw in progress (its temporary file)
            try:
                st = path.stat()
            except OSError:
                continue
            found.append((st.st_mtime, path, st.st_size))
        found.sort()
        self._files = OrderedDict((path, size) for _, path, size in found)
        self._total = sum(size for _, _, size in found)

    def hit(self, path: Path) -> bool:
        """Whether `path` is cached; if so it becomes the most recently used."""
        try:
            os.utime(path)
        except OSError:
            return False
        with self._lock:
            self._load()
            assert self._files is not None
            if path not in self._files:  # drawn before this index was built
                self._files[path] = path.stat().st_size
                self._total += self._files[path]
            self._files.move_to_end(path)
        return True

    def reserve(self) -> None:
        """Before a draw: free cached files while the disk is under its reserve; 503 if
        the cache alone cannot bring it back above."""
        if self.min_free_bytes <= 0:
            return
        with self._lock:
            self._load()
            while free_bytes(self.root) < self.min_free_bytes:
                if not self._evict_oldest(keep=None):
                    raise ProblemError(
                        503, "insufficient-storage", "Out of disk space",
                        "the server's data disk is below its free-space reserve; pictures "
                        "already drawn are served, new ones are not drawn until space is "
                        "freed", headers={"Retry-After": str(DISK_RETRY_AFTER)})

    def add(self, path: Path) -> None:
        """After a draw: count `path`, then delete the least recently used files until the
        cache fits in max_bytes (never `path` itself)."""
        size = path.stat().st_size
        with self._lock:
            self._load()
            assert self._files is not None
            self._total += size - self._files.pop(path, 0)
            self._files[path] = size
            while self._total > self.max_bytes and self._evict_oldest(keep=path):
                pass

    def _evict_oldest(self, keep: Path | None) -> bool:
        """Delete the least recently used file other than `keep`; False if none is left."""
        assert self._files is not None
        for path in self._files:
            if path != keep:
                break
        else:
            return False
        self._total -= self._files.pop(path)
        path.unlink(missing_ok=True)  # gone already if its results expired
        return True

