"""The worker process: runs jobs one after another with the engine (Taichi lives here only).

Started by the supervisor with the multiprocessing *spawn* context (never fork: a child
forked after `ti.init` hangs, taichi#6725). It talks to the supervisor over a pipe:

    supervisor -> worker   ("run", order)  |  ("stop",)
    worker -> supervisor   ("ready", pid)
                           ("progress", token, steps_done, steps_total)
                           ("progress", token, runs_ended, runs_total, runs_failed)  (sweeps)
                           ("resumed", token, step | None)   (a job resumed from the
                                           checkpoint of its lost attempt; None: that
                                           checkpoint was refused, it runs from step 0)
                           ("result", token, {"summary", "checksums", "rss"}
                                           | {"problem", "rss"})

Cancellation is a shared integer the supervisor sets (read between engine steps through
`should_stop`), so it works while the worker is busy and never reads the pipe mid-job.
The worker also stops when its parent disappears (the API was killed): the restarted
service re-runs the job, and this orphan must not keep the CPU.

An order's `kind` picks its runner (`orders.ORDERS`); parsing and re-admitting the stored
spec, and turning whatever a runner raises into the attempt's problem, are one path here
for every kind.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import traceback
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

from .admission import LimitError, admit
from .disk import disk_full_problem, is_disk_full, scrub_paths
from .limits import Limits
from .orders import ORDERS, Attempt
from .problems import cluster_problem, problem

log = logging.getLogger("flocklab.worker")


def worker_main(conn: Connection, cancel_flag: Any, config: dict[str, Any]) -> None:
    """Entry point of a worker process; returns when told to stop or orphaned."""
    parent = os.getppid()
    # Importing the engine here, not at module level: this module is also imported by
    # the API process (to name the target), which must never load Taichi.
    from flocklab.service.execute import execute_to_dir

    def orphaned() -> bool:
        return os.getppid() != parent

    if config.get("warmup_preset"):
        _warm_up(execute_to_dir, config["warmup_preset"], Path(config["scratch_dir"]))
    conn.send(("ready", os.getpid()))
    while not orphaned():
        try:
            msg = conn.recv()
        except (EOFError, OSError):
            return
        if msg[0] == "stop":
            return
        order = msg[1]
        outcome = _attempt(Attempt(order, conn, lambda: cancel_flag.value != 0 or orphaned()))
        outcome["rss"] = _rss_bytes()
        try:
            conn.send(("result", order["token"], outcome))
        except (BrokenPipeError, OSError):
            return


def _attempt(attempt: Attempt) -> dict[str, Any]:
    """Re-validate and re-admit the stored spec, then run one attempt of it with its
    kind's runner; every failure becomes a problem body."""
    from pydantic import ValidationError

    from flocklab.kernels.result import BackendUnavailable
    from flocklab.schemas import field_errors
    from flocklab.schemas.sweep import SweepError
    from flocklab.service.sweeps.ray_executor import ClusterError

    order = attempt.order
    kind = order.get("kind", "job")
    how = ORDERS[kind]
    try:
        spec = how.spec.model_validate_json(order["scenario"])
        admit(spec, Limits(**order["limits"]))
    except (ValidationError, SweepError) as exc:
        errors = field_errors(exc) if isinstance(exc, ValidationError) else exc.errors
        return {"problem": problem(f"invalid-{how.noun}", f"Invalid {how.noun}", 422,
                                   f"the stored {how.noun} no longer validates",
                                   errors=[e.model_dump() for e in errors])}
    except LimitError as exc:
        return {"problem": problem("limit-exceeded", "Over this service's limits", 422,
                                   str(exc), errors=[e.model_dump() for e in exc.errors],
                                   **exc.numbers)}
    try:
        return how.run(spec, attempt)
    except BackendUnavailable as exc:
        backend = {"backend": spec.backend} if kind == "job" else {}
        return {"problem": problem("backend-unavailable", "Backend unavailable", 503,
                                   scrub_paths(str(exc)), **backend)}
    except ClusterError as exc:  # unreachable, or lost mid-run: a sweep's finished runs stay
        return {"problem": cluster_problem(exc)}
    except SweepError as exc:  # e.g. a measure's observable the model does not have
        return {"problem": problem("invalid-sweep", "Invalid sweep", 422, str(exc),
                                   errors=[e.model_dump() for e in exc.errors])}
    except Exception as exc:  # an engine or runner bug must fail this attempt, not the worker
        log.error("%s %s failed:\n%s", kind, order["job_id"], traceback.format_exc())
        if is_disk_full(exc):
            return {"problem": disk_full_problem(f"while the {kind} wrote its results")}
        # The message may name files under the data directory: clients never see paths.
        return {"problem": problem("internal-error", "Internal error", 500,
                                   scrub_paths(f"{type(exc).__name__}: {exc}"))}


def _warm_up(execute_to_dir: Any, preset: str, scratch: Path) -> None:
    """Run a tiny version of a preset so Taichi is initialised and its kernels compiled
    (and the offline cache written) before the first real job arrives."""
    from flocklab.schemas import PRESETS, Scenario

    try:
        spec = PRESETS[preset].build()
        spec["time"]["steps"] = min(spec["time"]["steps"], 5)
        if spec["initial"].get("kind") == "random":
            spec["initial"]["N"] = min(spec["initial"]["N"], 64)
        spec.setdefault("recording", {})["every"] = 1
        scenario = Scenario.model_validate_json(json.dumps(spec))
        out = scratch / f"warmup-{os.getpid()}"
        execute_to_dir(scenario, out)
        shutil.rmtree(out, ignore_errors=True)
    except Exception:  # warm-up is an optimisation: a failure must not stop the worker
        log.warning("worker warm-up with preset %r failed:\n%s", preset, traceback.format_exc())


def _rss_bytes() -> int:
    """Current resident set size (Linux /proc; 0 elsewhere)."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError):
        return 0
