"""Admission: whether this service accepts a job of either kind, and what the store keeps
of it (R12, R13).

One function, `admit`, for a run's scenario and for a sweep: the API calls it before
storing a submission and the worker again before running an attempt, so a job stored by
an older, laxer configuration cannot run past the current limits. A run is held to the
per-job limits (`limits.check_limits`); a sweep to its run count, its total agent-steps
and, run by run, the per-job limits. Pure Python (no FastAPI, no Taichi): both processes
import it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from flocklab.schemas import FieldError, Scenario

from .limits import Limits, check_limits

if TYPE_CHECKING:
    from flocklab.schemas.sweep import Sweep

# Enough per-run errors to see the pattern; a 10^5-run sweep would flood the answer.
MAX_REPORTED = 20


class LimitError(Exception):
    """A job over this service's limits: the field errors and the numbers behind them
    (a sweep's run count and agent-steps, with their maxima; none for a run)."""

    def __init__(self, errors: list[FieldError], numbers: dict[str, int] | None = None):
        self.errors = errors
        self.numbers = numbers or {}
        super().__init__("; ".join(f"{e.loc}: {e.msg}" for e in errors))


@dataclass(frozen=True)
class Admitted:
    """What the job store keeps of an admitted job, for either kind: a sweep's
    `n_agents` is its largest run's N and its `steps_total` its run count (its progress
    counts runs)."""

    model_kind: str
    n_agents: int
    steps_total: int


def admit(spec: Scenario | Sweep, limits: Limits) -> Admitted:
    """Admit a scenario or a sweep, or raise LimitError (a sweep whose run is invalid
    raises `schemas.sweep.SweepError`, before any limit)."""
    if isinstance(spec, Scenario):
        errors = check_limits(spec, limits)
        if errors:
            raise LimitError(errors)
        return Admitted(spec.model.kind, spec.n_agents, spec.time.steps)
    return _admit_sweep(spec, limits)


def _admit_sweep(sweep: Sweep, limits: Limits) -> Admitted:
    """The run count is checked before the runs are expanded (expanding is the costly
    part); then, in one pass over the runs expanded lazily (`Sweep.iter_runs`: memory
    does not grow with the sweep), the total agent-steps (N x steps summed over runs) and
    each run against the per-job limits, errors naming the run and the field."""
    n_runs = sweep.n_runs
    numbers = {"runs": n_runs, "max_runs": limits.max_sweep_runs,
               "max_agent_steps": limits.max_sweep_agent_steps}
    if n_runs > limits.max_sweep_runs:
        raise LimitError([FieldError(
            loc="axes", type="limit_exceeded",
            msg=f"the sweep has {n_runs} runs ({sweep.n_points} grid points x replicas), "
                f"over this service's limit of {limits.max_sweep_runs}")], numbers)
    agent_steps = max_agents = count = 0
    kind = ""
    errors: list[FieldError] = []
    for run in sweep.iter_runs():
        sc = run.scenario
        count += 1
        kind = kind or sc.model.kind
        agent_steps += sc.n_agents * sc.time.steps
        max_agents = max(max_agents, sc.n_agents)
        if len(errors) < MAX_REPORTED:
            errors += [FieldError(loc=f"runs[{run.index}].{e.loc}", type=e.type,
                                  msg=f"{e.msg} (run {run.index})")
                       for e in check_limits(sc, limits)]
    if agent_steps > limits.max_sweep_agent_steps:
        raise LimitError([FieldError(
            loc="axes", type="limit_exceeded",
            msg=f"the sweep's {n_runs} runs total {agent_steps} agent-steps (N x steps), "
                f"over this service's limit of {limits.max_sweep_agent_steps}")],
            {**numbers, "agent_steps": agent_steps})
    if errors:
        raise LimitError(errors[:MAX_REPORTED], {**numbers, "agent_steps": agent_steps})
    return Admitted(kind, max_agents, count)
