"""flocklab's engine: Taichi kernels behind one numpy-facing entry, `run`.

Importing this package never calls `ti.init`; `run` initialises the requested backend in
the calling process (on the calling thread) the first time it is needed.
"""

import os

# Taichi prints a banner on import and a line on init to stdout, which belongs to the
# user's output (the CLI prints its JSON summary there).
os.environ.setdefault("ENABLE_TAICHI_HEADER_PRINT", "0")
# ti.init otherwise starts a thread that posts a client id to Taichi's web server once a
# day: traffic off this machine that neither a user nor an offline container asked for.
os.environ.setdefault("TI_SKIP_VERSION_CHECK", "ON")

from .engine import run, run_batch
from .result import BackendUnavailable, FrameSink, RunResult, SimulationDiverged

__all__ = ["BackendUnavailable", "FrameSink", "RunResult", "SimulationDiverged", "run", "run_batch"]
