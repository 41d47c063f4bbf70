"""Jobs: the SQLite store, the results folder, the supervisor and its worker processes.

Nothing here imports FastAPI; only `worker.worker_main`, inside a spawned process,
imports the engine (and so Taichi).
"""

from .limits import Limits, check_limits
from .runtime import DataDirLocked, JobRuntime, data_dir_locked
from .store import STATUSES, TERMINAL, IdempotencyConflict, Job, JobStore, NewJob, QueueFull
from .supervisor import SupervisorConfig

__all__ = [
    "STATUSES",
    "TERMINAL",
    "DataDirLocked",
    "IdempotencyConflict",
    "Job",
    "JobRuntime",
    "JobStore",
    "Limits",
    "NewJob",
    "QueueFull",
    "SupervisorConfig",
    "check_limits",
    "data_dir_locked",
]
