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
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import shutil
import traceback
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

from .disk import disk_full_problem, is_disk_full, scrub_paths
from .limits import Limits, check_limits
from .problems import cluster_problem, problem
from .results import checksums

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
        token = order["token"]

        def on_progress(done: int, total: int, token: str = token) -> None:
            # A broken pipe means the supervisor is gone: should_stop ends the run.
            with contextlib.suppress(OSError):
                conn.send(("progress", token, int(done), int(total)))

        def should_stop() -> bool:
            return cancel_flag.value != 0 or orphaned()

        def on_resumed(step: int | None, token: str = token) -> None:
            with contextlib.suppress(OSError):
                conn.send(("resumed", token, step))

        if order.get("kind") == "sweep":
            from .sweep_worker import run_sweep_order

            outcome = run_sweep_order(order, conn, should_stop)
        else:
            outcome = _run_order(order, on_progress, should_stop, on_resumed)
        outcome["rss"] = _rss_bytes()
        try:
            conn.send(("result", token, outcome))
        except (BrokenPipeError, OSError):
            return


def _run_order(order: dict[str, Any], on_progress: Any, should_stop: Any,
               on_resumed: Any) -> dict[str, Any]:
    """Re-validate and run one attempt (from its lost predecessor's checkpoint when the
    order says `resume`); every failure becomes a problem body."""
    from pydantic import ValidationError

    from flocklab.kernels.result import BackendUnavailable
    from flocklab.schemas import Scenario, field_errors

    try:
        scenario = Scenario.model_validate_json(order["scenario"])
    except ValidationError as exc:
        errors = [e.model_dump() for e in field_errors(exc)]
        return {"problem": problem("invalid-scenario", "Invalid scenario", 422,
                                   "the stored scenario no longer validates", errors=errors)}
    errors = check_limits(scenario, Limits(**order["limits"]))
    if errors:
        return {"problem": problem("limit-exceeded", "Over this service's limits", 422,
                                   errors[0].msg, errors=[e.model_dump() for e in errors])}
    from flocklab.service.sweeps.factory import make_executor
    from flocklab.service.sweeps.ray_executor import ClusterError

    executor = make_executor(order.get("executor"))
    on_ray = (order.get("executor") or {}).get("kind") == "ray"
    # A Ray task gets its own threads: the CPUs it reserved on the cluster.
    scenario, notes = _fit_threads(scenario, None if on_ray else order.get("threads"))
    out_dir = Path(order["out_dir"])
    try:
        if order.get("resume"):
            summary = _resume(executor, scenario, out_dir, notes, on_progress, should_stop,
                              on_resumed)
        else:
            summary = executor.run_job(scenario, out_dir, on_progress=on_progress,
                                       should_stop=should_stop)
    except BackendUnavailable as exc:
        return {"problem": problem("backend-unavailable", "Backend unavailable", 503,
                                   scrub_paths(str(exc)), backend=scenario.backend)}
    except ClusterError as exc:
        return {"problem": cluster_problem(exc)}
    except Exception as exc:  # an engine bug must fail this job, not the worker
        log.error("job %s failed:\n%s", order["job_id"], traceback.format_exc())
        if is_disk_full(exc):
            return {"problem": disk_full_problem("while the job wrote its results")}
        # The message may name files under the data directory: clients never see paths.
        return {"problem": problem("internal-error", "Internal error", 500,
                                   scrub_paths(f"{type(exc).__name__}: {exc}"))}
    if not (out_dir / "summary.json").exists():  # a job cancelled on Ray left no folder
        return {"summary": summary, "checksums": {}}
    if scenario.backend == "auto":
        ran = summary.get("backend")
        notes.append(f"backend 'auto' ran on {ran!r}" + (
            ": no working GPU (cuda, vulkan) was found" if ran == "cpu" else ""))
    if notes:
        try:
            _add_to_summary(out_dir, summary, backend_requested=scenario.backend, notes=notes)
        except OSError as exc:
            if is_disk_full(exc):
                return {"problem": disk_full_problem("while the job wrote its results")}
            return {"problem": problem("internal-error", "Internal error", 500,
                                       scrub_paths(f"{type(exc).__name__}: {exc}"))}
    return {"summary": summary, "checksums": checksums(out_dir)}


def _resume(executor: Any, scenario: Any, out_dir: Path, notes: list[str], on_progress: Any,
            should_stop: Any, on_resumed: Any) -> dict[str, Any]:
    """Go on from the checkpoint the supervisor handed this attempt (the lost attempt's,
    `ResultStore.adopt_checkpoint`), with that run's own scenario.json; a checkpoint that
    cannot be resumed exactly (corrupted, another engine version) is dropped, with a
    note, and the job runs again from step 0 (bits are never continued inexactly)."""
    from flocklab.service.checkpoints import CheckpointRefused
    from flocklab.service.execute import resume_dir

    try:
        return resume_dir(out_dir, on_progress=on_progress, should_stop=should_stop,
                          on_resumed=on_resumed)
    except CheckpointRefused as exc:
        log.warning("job folder %s: checkpoint refused, running from step 0: %s",
                    out_dir.name, exc)
        on_resumed(None)
        for p in (out_dir, *out_dir.parent.glob(f".{out_dir.name}.*")):
            shutil.rmtree(p, ignore_errors=True)
        notes.append(f"the lost attempt's checkpoint was refused ({scrub_paths(str(exc))}); "
                     "the job ran again from step 0")
        return executor.run_job(scenario, out_dir, on_progress=on_progress,
                                should_stop=should_stop)


def _fit_threads(scenario: Any, allowed: int | None) -> tuple[Any, list[str]]:
    """The scenario with its thread count fitted to this worker's CPUs (R13), and a note
    when a request had to be capped: more threads than cores only contend for them."""
    if not allowed:
        return scenario, []
    if scenario.threads is None:
        return scenario.model_copy(update={"threads": allowed}), []
    if scenario.threads > allowed:
        note = (f"threads capped from {scenario.threads} to {allowed}, the CPUs this "
                f"service allots to a job")
        return scenario.model_copy(update={"threads": allowed}), [note]
    return scenario, []


def _add_to_summary(out_dir: Path, summary: dict[str, Any], **extra: Any) -> None:
    """Record what the service changed or chose in the job's summary.json (and `summary`)."""
    summary.update(extra)
    path = out_dir / "summary.json"
    tmp = path.with_name(".summary.json.tmp")
    tmp.write_text(json.dumps(summary, indent=2, allow_nan=False))
    os.replace(tmp, path)


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
