"""Report which Taichi backend a job actually runs on in this container.

Prints one JSON line: the backend asked for, the one that ran a tiny Vicsek job, whether
each GPU backend initialises here, and whether the NVIDIA driver library was mounted.
Exits 0 when the requested backend ran, 3 (the CLI's "backend not available") otherwise.

    docker run --rm --gpus all flocklab:cuda python docker/probe_backend.py --backend cuda
"""

from __future__ import annotations

import argparse
import ctypes
import json
import sys

from flocklab.kernels import engine, runtime
from flocklab.kernels.result import BackendUnavailable
from flocklab.schemas import Scenario

TINY = {"model": {"kind": "vicsek", "eta": 0.5}, "space": {"kind": "periodic", "L": 4},
        "neighbours": {"radius": 1}, "initial": {"kind": "random", "N": 64},
        "time": {"steps": 3}, "recording": {"every": 0}}


def libcuda_mounted() -> bool:
    """Whether the NVIDIA driver library (mounted by `--gpus`) loads in this process."""
    try:
        ctypes.CDLL("libcuda.so.1")
    except OSError:
        return False
    return True


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--backend", default="auto", choices=["auto", "cpu", "cuda", "vulkan"])
    args = p.parse_args(argv)
    report: dict = {
        "requested": args.backend,
        "libcuda": libcuda_mounted(),
        "gpu_available": {a: runtime.gpu_available(a) for a in ("cuda", "vulkan")},
    }
    try:
        result = engine.run(Scenario.model_validate({**TINY, "backend": args.backend}))
        report.update(ran=result.backend, status=result.status)
    except BackendUnavailable as exc:
        report.update(ran=None, error=str(exc))
    print(json.dumps(report), flush=True)
    ok = report["ran"] is not None and args.backend in ("auto", report["ran"])
    return 0 if ok else 3


if __name__ == "__main__":
    sys.exit(main())
