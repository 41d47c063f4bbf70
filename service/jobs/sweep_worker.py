"""Running a sweep inside a worker process (imported there only: the runner loads Taichi).

The sweep runs with `service.sweeps.runner.run_sweep` into the attempt's folder, which
the supervisor gave this attempt from a lost predecessor when there was one: the runner
skips the runs already finished there, so a retry continues instead of starting over,
and continues a checkpointed run from its checkpoint, which it reports to the supervisor
as ("run_resumed", token, run, step | None).
"""

from __future__ import annotations

import contextlib
import logging
import os
import traceback
from collections.abc import Callable
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

from .disk import disk_full_problem, is_disk_full, scrub_paths
from .limits import Limits
from .problems import cluster_problem, problem
from .results import SWEEP_FILES, checksums
from .sweep_limits import SweepLimitError, check_sweep

log = logging.getLogger("flocklab.worker")


def run_sweep_order(order: dict[str, Any], conn: Connection,
                    should_stop: Callable[[], bool]) -> dict[str, Any]:
    """Re-validate and run one sweep attempt; every failure becomes a problem body."""
    from pydantic import ValidationError

    from flocklab.kernels.result import BackendUnavailable
    from flocklab.schemas import field_errors
    from flocklab.schemas.sweep import Sweep, SweepError
    from flocklab.service.sweeps.runner import run_sweep

    token = order["token"]
    try:
        sweep = Sweep.model_validate_json(order["scenario"])
        check_sweep(sweep, Limits(**order["limits"]))
    except (ValidationError, SweepError) as exc:
        errors = field_errors(exc) if isinstance(exc, ValidationError) else exc.errors
        return {"problem": problem("invalid-sweep", "Invalid sweep", 422,
                                   "the stored sweep no longer validates",
                                   errors=[e.model_dump() for e in errors])}
    except SweepLimitError as exc:
        return {"problem": problem("limit-exceeded", "Over this service's limits", 422,
                                   str(exc), errors=[e.model_dump() for e in exc.errors],
                                   **exc.numbers)}
    if order.get("threads"):
        # Thread count = the CPUs this worker is allotted (R13); a run's own `threads`
        # still wins, since the engine reads this only when the scenario names none.
        os.environ["FLOCKLAB_THREADS"] = str(order["threads"])

    def on_progress(p: Any) -> None:
        # A broken pipe means the supervisor is gone: should_stop ends the sweep. A
        # sweep's steps_done counts the runs that ended, failed ones included.
        with contextlib.suppress(OSError):
            conn.send(("progress", token, int(p.runs_done + p.runs_failed),
                       int(p.runs_total), int(p.runs_failed)))

    def on_resumed(run: int, step: int | None) -> None:
        with contextlib.suppress(OSError):
            conn.send(("run_resumed", token, run, step))

    from flocklab.service.sweeps.factory import make_executor
    from flocklab.service.sweeps.ray_executor import ClusterError

    out_dir = Path(order["out_dir"])
    try:
        outcome = run_sweep(sweep, out_dir, on_progress=on_progress, should_stop=should_stop,
                            executor=make_executor(order.get("executor")),
                            on_resumed=on_resumed)
    except BackendUnavailable as exc:
        return {"problem": problem("backend-unavailable", "Backend unavailable", 503,
                                   str(exc))}
    except ClusterError as exc:  # unreachable, or lost mid-sweep: finished runs are kept
        return {"problem": cluster_problem(exc)}
    except SweepError as exc:  # e.g. a measure's observable the model does not have
        return {"problem": problem("invalid-sweep", "Invalid sweep", 422, str(exc),
                                   errors=[e.model_dump() for e in exc.errors])}
    except Exception as exc:  # a runner bug must fail this sweep, not the worker
        log.error("sweep %s failed:\n%s", order["job_id"], traceback.format_exc())
        if is_disk_full(exc):
            return {"problem": disk_full_problem("while the sweep wrote its results")}
        # The message may name files under the data directory: clients never see paths.
        return {"problem": problem("internal-error", "Internal error", 500,
                                   scrub_paths(f"{type(exc).__name__}: {exc}"))}
    summary = {"status": outcome.status, "runs_done": outcome.runs_done,
               "runs_failed": outcome.runs_failed, "runs_total": outcome.runs_total,
               "runs_ended": outcome.runs_done + outcome.runs_failed,
               "runs_resumed": outcome.runs_resumed}
    return {"summary": summary, "checksums": checksums(out_dir, SWEEP_FILES)}
