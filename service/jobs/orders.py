"""The order of each kind of job: how a worker runs one attempt of a run or a sweep.

`ORDERS[kind]` names the kind's spec (what the store's `scenario` column holds) and its
runner. The worker (`worker._attempt`) parses and re-admits the spec, then calls the
runner; whatever a runner raises becomes the attempt's problem there, the same for both
kinds. A runner returns the attempt's outcome: `{"summary", "checksums"}`.

Imported by the API process too (through `worker`): the engine is imported inside the
runners only.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

from pydantic import BaseModel

from flocklab.schemas import Scenario
from flocklab.schemas.sweep import Sweep

from .disk import scrub_paths
from .results import SWEEP_FILES, checksums

log = logging.getLogger("flocklab.worker")


@dataclass(frozen=True)
class Attempt:
    """One attempt as its runner sees it: the supervisor's order and the ways back."""

    order: dict[str, Any]
    conn: Connection
    should_stop: Callable[[], bool]

    def send(self, what: str, *values: Any) -> None:
        """Tell the supervisor `(what, token, *values)`. A broken pipe means the
        supervisor is gone: `should_stop` then ends the attempt."""
        with contextlib.suppress(OSError):
            self.conn.send((what, self.order["token"], *values))

    @property
    def out_dir(self) -> Path:
        return Path(self.order["out_dir"])

    def executor(self) -> Any:
        from flocklab.service.sweeps.factory import make_executor

        return make_executor(self.order.get("executor"))


def run_job(scenario: Scenario, attempt: Attempt) -> dict[str, Any]:
    """One run, from its lost predecessor's checkpoint when the order says `resume`;
    progress is (steps done, steps in all)."""
    order = attempt.order
    executor = attempt.executor()
    on_ray = (order.get("executor") or {}).get("kind") == "ray"
    # A Ray task gets its own threads: the CPUs it reserved on the cluster.
    scenario, notes = _fit_threads(scenario, None if on_ray else order.get("threads"))
    out_dir = attempt.out_dir

    def on_progress(done: int, total: int) -> None:
        attempt.send("progress", int(done), int(total))

    if order.get("resume"):
        summary = _resume(executor, scenario, out_dir, notes, on_progress, attempt)
    else:
        summary = executor.run_job(scenario, out_dir, on_progress=on_progress,
                                   should_stop=attempt.should_stop)
    if not (out_dir / "summary.json").exists():  # a job cancelled on Ray left no folder
        return {"summary": summary, "checksums": {}}
    if scenario.backend == "auto":
        ran = summary.get("backend")
        notes.append(f"backend 'auto' ran on {ran!r}" + (
            ": no working GPU (cuda, vulkan) was found" if ran == "cpu" else ""))
    if notes:
        _add_to_summary(out_dir, summary, backend_requested=scenario.backend, notes=notes)
    return {"summary": summary, "checksums": checksums(out_dir)}


def run_sweep(sweep: Sweep, attempt: Attempt) -> dict[str, Any]:
    """One sweep attempt, with `service.sweeps.runner.run_sweep` into the attempt's
    folder, which the supervisor gave it from a lost predecessor when there was one: the
    runner skips the runs already finished there, so a retry continues instead of
    starting over, and continues a checkpointed run from its checkpoint, which it reports
    to the supervisor as ("run_resumed", token, run, step | None). Progress is (runs
    ended, runs in all, runs failed)."""
    from flocklab.service.sweeps.runner import run_sweep as run

    if attempt.order.get("threads"):
        # Thread count = the CPUs this worker is allotted (R13); the executors cap a
        # run's own `threads` at it too.
        os.environ["FLOCKLAB_THREADS"] = str(attempt.order["threads"])

    def on_progress(p: Any) -> None:
        # A sweep's steps_done counts the runs that ended, failed ones included.
        attempt.send("progress", int(p.runs_done + p.runs_failed), int(p.runs_total),
                     int(p.runs_failed))

    def on_resumed(run_index: int, step: int | None) -> None:
        attempt.send("run_resumed", run_index, step)

    outcome = run(sweep, attempt.out_dir, on_progress=on_progress,
                  should_stop=attempt.should_stop, executor=attempt.executor(),
                  on_resumed=on_resumed)
    summary = {"status": outcome.status, "runs_done": outcome.runs_done,
               "runs_failed": outcome.runs_failed, "runs_total": outcome.runs_total,
               "runs_ended": outcome.runs_done + outcome.runs_failed,
               "runs_resumed": outcome.runs_resumed}
    return {"summary": summary, "checksums": checksums(attempt.out_dir, SWEEP_FILES)}


@dataclass(frozen=True)
class Order:
    """A kind of job as a worker runs it."""

    spec: type[BaseModel]  # what the store's `scenario` column holds for this kind
    noun: str  # the spec's name in problems: "invalid-<noun>", "the stored <noun> ..."
    run: Callable[[Any, Attempt], dict[str, Any]]


ORDERS: dict[str, Order] = {"job": Order(Scenario, "scenario", run_job),
                            "sweep": Order(Sweep, "sweep", run_sweep)}


def _resume(executor: Any, scenario: Scenario, out_dir: Path, notes: list[str],
            on_progress: Callable[[int, int], None], attempt: Attempt) -> dict[str, Any]:
    """Go on from the checkpoint the supervisor handed this attempt (the lost attempt's,
    `ResultStore.adopt_checkpoint`), with that run's own scenario.json; a checkpoint that
    cannot be resumed exactly (corrupted, another engine version) is dropped, with a
    note, and the job runs again from step 0 (bits are never continued inexactly)."""
    from flocklab.service.checkpoints import CheckpointRefused
    from flocklab.service.execute import resume_dir

    def on_resumed(step: int | None) -> None:
        attempt.send("resumed", step)

    try:
        return resume_dir(out_dir, on_progress=on_progress, should_stop=attempt.should_stop,
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
                                should_stop=attempt.should_stop)


def _fit_threads(scenario: Scenario, allowed: int | None) -> tuple[Scenario, list[str]]:
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
