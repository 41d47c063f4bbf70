"""flocklab's engine: Taichi kernels behind one numpy-facing entry, `run`.

Importing this package never calls `ti.init` (nor imports Taichi: the names below load
on first use); `run` initialises the requested backend in the calling process (on the
calling thread) the first time it is needed.
"""

import os

# Taichi prints a banner on import and a line on init to stdout, which belongs to the
# user's output (the CLI prints its JSON summary there).
os.environ.setdefault("ENABLE_TAICHI_HEADER_PRINT", "0")
# ti.init otherwise starts a thread that posts a client id to Taichi's web server once a
# day: traffic off this machine that neither a user nor an offline container asked for.
os.environ.setdefault("TI_SKIP_VERSION_CHECK", "ON")

# The public names load on first use (PEP 562): the engine imports Taichi (~0.8 s), and
# the numpy-only parts of the model packages (leader paths, fixed graphs, offset
# schedules, which `flocklab render` draws from) must not pay for it.
_PUBLIC = {"run": "engine", "run_batch": "engine", "PATHS": "engine",
           "PathUnavailable": "engine", "BackendUnavailable": "result",
           "FrameSink": "result", "RunResult": "result", "SimulationDiverged": "result"}

__all__ = sorted(_PUBLIC)


def __getattr__(name: str):
    from importlib import import_module

    if name in _PUBLIC:
        value = getattr(import_module(f".{_PUBLIC[name]}", __name__), name)
    else:  # a submodule, as `kernels.engine` was before these names were lazy
        try:
            value = import_module(f".{name}", __name__)
        except ModuleNotFoundError:
            raise AttributeError(f"module {__name__!r} has no attribute {name!r}") from None
    globals()[name] = value
    return value
