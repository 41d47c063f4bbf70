"""Taichi initialisation: one backend per process, resolved carefully, never on import.

Facts this module relies on (../shared/RELIABILITY.md, taichi 1.7.4):
- `ti.init(arch=ti.gpu)` or `opengl` can segfault on a machine without a GPU, and
  `arch=ti.cuda` silently falls back to the CPU. So "auto" probes each GPU backend in a
  child process first, and every explicit GPU request is checked after init.
- The probe child is a plain `subprocess` running the interpreter, not a
  `multiprocessing` child: the job service's workers are daemonic multiprocessing
  processes, which may not start multiprocessing children of their own.
- A backend whose driver library cannot even be found is unavailable without a probe
  (importing Taichi in a child costs seconds).
- Kernels may only be launched from the thread that called `ti.init`.
"""

from __future__ import annotations

import contextlib
import ctypes
import gc
import io
import os
import subprocess
import sys
import threading
from dataclasses import dataclass

import numpy as np

from .result import BackendUnavailable

_GPU_ORDER = ("cuda", "vulkan")
# Taichi's arch names for what we call "cpu".
_ARCH_NAMES = {"x64": "cpu", "arm64": "cpu"}


@dataclass(frozen=True)
class DevicePolicy:
    """How the neighbour grids build on a device: decided once from the backend, then
    handed to every grid, so a test can build a GPU variant on the CPU."""

    serial_scatter: bool
    """The serial scan and stable scatter (fastest on a CPU), or a blocked parallel scan and
    atomic slots then a per-bucket sort by old index (a GPU); both give the same bucket
    starts and permutation."""
    dense_grid: bool
    """Whether the plane may use the dense row-by-row grid (its scan is serial: a CPU's)."""
    cell_blocks: bool = True
    """Whether Vicsek's step in the box goes by cell blocks (kernels/space/blocks.py: a
    thread per cell, its agents four at a time: a CPU's vector unit) or keeps a thread per
    agent (a GPU's: cells of unequal counts would stall a warp). The same bits either way."""

    @staticmethod
    def for_backend(backend: str) -> DevicePolicy:
        cpu = backend == "cpu"
        return DevicePolicy(serial_scatter=cpu, dense_grid=cpu, cell_blocks=cpu)


@dataclass(frozen=True)
class Runtime:
    backend: str  # what actually runs: "cpu", "cuda" or "vulkan"
    threads: int | None
    thread_id: int
    precision: str = "float64"  # Taichi's default_fp: "float64" or "float32"

    @property
    def real(self) -> type[np.floating]:
        """The numpy twin of the kernels' float type (`float` in a kernel is default_fp)."""
        return np.float32 if self.precision == "float32" else np.float64

    @property
    def policy(self) -> DevicePolicy:
        return DevicePolicy.for_backend(self.backend)


_current: Runtime | None = None
_probe_cache: dict[str, bool] = {}


def default_threads() -> int:
    """CPU threads: FLOCKLAB_THREADS, else the cores this process may use (cgroup-aware)."""
    env = os.environ.get("FLOCKLAB_THREADS")
    if env:
        return max(1, int(env))
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - non-Linux
        return os.cpu_count() or 1


# Run by the probe child: exit 0 only when Taichi started on exactly this arch (no silent
# CPU fallback). Output is discarded; a crash is just a non-zero exit.
_PROBE = """
import sys
import taichi as ti
ti.init(arch=getattr(ti, sys.argv[1]), enable_fallback=False, log_level=ti.ERROR)
sys.exit(0 if ti.lang.impl.current_cfg().arch.name == sys.argv[1] else 1)
"""
# The driver library each GPU backend loads; without it Taichi cannot start there.
_DRIVER_LIBS = {"cuda": ("libcuda.so.1", "libcuda.so"), "vulkan": ("libvulkan.so.1",
                                                                  "libvulkan.so")}


def _driver_present(arch_name: str) -> bool:
    """Whether the backend's driver library loads in this process (cheap, never crashes)."""
    for name in _DRIVER_LIBS.get(arch_name, ()):
        try:
            ctypes.CDLL(name)
            return True
        except OSError:
            continue
    return False


def gpu_available(arch_name: str, timeout: float = 60.0) -> bool:
    """Whether `arch_name` initialises in a fresh child process (a crash there is safe)."""
    if arch_name not in _probe_cache:
        ok = False
        if _driver_present(arch_name):
            try:
                done = subprocess.run([sys.executable, "-c", _PROBE, arch_name],
                                      stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                      stderr=subprocess.DEVNULL, timeout=timeout, check=False)
                ok = done.returncode == 0
            except (OSError, subprocess.TimeoutExpired):
                ok = False
        _probe_cache[arch_name] = ok
    return _probe_cache[arch_name]


def resolve_backend(requested: str) -> str:
    """The backend to start: "auto" takes the first working GPU, else the CPU; an explicit
    GPU request is probed in a child first, since a failed GPU init may kill the process."""
    if requested == "auto":
        return next((a for a in _GPU_ORDER if gpu_available(a)), "cpu")
    if requested in _GPU_ORDER and not gpu_available(requested):
        raise BackendUnavailable(
            f"backend {requested!r} is not available on this machine (no working "
            f"{requested} device); use backend 'cpu' or 'auto'"
        )
    return requested


def current() -> Runtime:
    """The runtime `ensure` started in this process."""
    if _current is None:
        raise RuntimeError("Taichi is not initialised: call kernels.runtime.ensure first")
    return _current


def real() -> type[np.floating]:
    """The numpy float type of the running kernels (np.float32 or np.float64)."""
    return current().real


def as_real(a) -> np.ndarray:
    """`a` as a contiguous array of the kernels' float type, rounded once on the host (a
    float64 array handed to a float32 ndarray would be narrowed by a Taichi kernel)."""
    return np.ascontiguousarray(a, dtype=real())


def wide(a) -> np.ndarray:
    """A device array on the host in float64 (no copy when it is float64 already): the
    host-side observables sum over N agents, which float32 would accumulate with an error
    growing with N (numpy sums a column of an (N, 2) array serially)."""
    return a.to_numpy().astype(np.float64, copy=False)


def next_above(x: float) -> float:
    """The next float above `x` in the kernels' precision: `d2 <= x` is `d2 < next_above(x)`
    in that type (a float64 nextafter would round back to x in float32)."""
    t = real()
    return float(np.nextafter(t(x), t(np.inf)))


def ensure(requested: str, threads: int | None = None, precision: str = "float64") -> Runtime:
    """Initialise Taichi for `requested` in this process (idempotent for the same choice).

    Switching backend, thread count or precision re-initialises Taichi (`ti.reset` +
    `ti.init`); every kernel then compiles again for the new default float type.
    """
    global _current
    import taichi as ti

    if precision not in ("float64", "float32"):
        raise ValueError(f"precision {precision!r}: float64 or float32")
    backend = resolve_backend(requested)
    n_threads = threads or default_threads()
    if _current is not None and (_current.backend, _current.threads, _current.precision) == (
            backend, n_threads, precision):
        if _current.thread_id != threading.get_ident():
            raise RuntimeError("Taichi kernels must run on the thread that called ti.init")
        return _current
    if _current is not None:
        # Taichi frees an array from its Python wrapper's __del__, by address, in the
        # program current at that moment. A wrapper of this runtime collected after the
        # reset would free whatever array of the next runtime then sits at that address
        # ("invalid DeviceAllocation" on its next launch, seen in the test suite). Arrays
        # held only by reference cycles are freed here, while their program exists.
        gc.collect()
        ti.reset()
    arch = getattr(ti, backend)
    kwargs: dict = {
        "arch": arch,
        "default_fp": ti.f32 if precision == "float32" else ti.f64,
        "default_ip": ti.i32,
        "offline_cache": True,
        "log_level": ti.WARN,
        "enable_fallback": False,
        # No FMA contraction or reassociation: distances computed here must equal the
        # brute-force reference bit for bit, so pairs exactly at the radius agree.
        "fast_math": False,
    }
    if backend == "cpu":
        kwargs["cpu_max_num_threads"] = n_threads
    cache_dir = os.environ.get("FLOCKLAB_TAICHI_CACHE")
    if cache_dir:
        kwargs["offline_cache_file_path"] = cache_dir
    try:
        with contextlib.redirect_stdout(io.StringIO()):  # "[Taichi] Starting on arch=..."
            ti.init(**kwargs)
    except Exception as exc:  # Taichi raises plain RuntimeError/AssertionError
        raise BackendUnavailable(f"backend {backend!r} failed to initialise: {exc}") from exc
    ran = ti.lang.impl.current_cfg().arch.name
    if _ARCH_NAMES.get(ran, ran) != backend:
        ti.reset()
        raise BackendUnavailable(f"backend {backend!r} requested but Taichi started {ran!r}")
    _current = Runtime(backend, n_threads, threading.get_ident(), precision)
    return _current
