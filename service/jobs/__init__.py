"""Jobs: the SQLite store, the results folder, the supervisor and its worker processes.

Nothing here imports FastAPI; only `worker.worker_main`, inside a spawned process,
imports the engine (and so Taichi).
"""

from .admission import Admitted, LimitError, admit
from .limits import Limits
from .runtime import DataDirLocked, JobRuntime, data_dir_locked
from .store import IdempotencyConflict, Job, JobStore, NewJob, QueueFull
from .supervisor import SupervisorConfig

__all__ = [
    "Admitted",
    "DataDirLocked",
    "IdempotencyConflict",
    "Job",
    "JobRuntime",
    "JobStore",
    "LimitError",
    "Limits",
    "NewJob",
    "QueueFull",
    "SupervisorConfig",
    "admit",
    "data_dir_locked",
]
