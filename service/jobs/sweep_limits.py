"""Admission limits of a sweep: its run count, its total agent-steps, and every expanded
run against the per-job limits. Pure Python, like `limits`: the API checks a sweep before
storing it and the worker again before running it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from flocklab.schemas import FieldError

from .limits import Limits, check_limits

if TYPE_CHECKING:
    from flocklab.schemas.sweep import Sweep, SweepRun

# Enough per-run errors to see the pattern; a 10^5-run sweep would flood the answer.
MAX_REPORTED = 20


class SweepLimitError(Exception):
    """A sweep over this service's limits: the field errors and the numbers behind them."""

    def __init__(self, errors: list[FieldError], numbers: dict[str, int] | None = None):
        self.errors = errors
        self.numbers = numbers or {}
        super().__init__("; ".join(f"{e.loc}: {e.msg}" for e in errors))


def check_sweep(sweep: Sweep, limits: Limits) -> list[SweepRun]:
    """The sweep's runs, once it is within every limit.

    The run count is checked before the runs are expanded (expanding is the costly
    part); then the total agent-steps (N x steps summed over runs) and each run against
    the per-job limits, errors naming the run and the field. Raises SweepLimitError, or
    `schemas.sweep.SweepError` when a run is invalid.
    """
    n_runs = sweep.n_runs
    numbers = {"runs": n_runs, "max_runs": limits.max_sweep_runs,
               "max_agent_steps": limits.max_sweep_agent_steps}
    if n_runs > limits.max_sweep_runs:
        raise SweepLimitError([FieldError(
            loc="axes", type="limit_exceeded",
            msg=f"the sweep has {n_runs} runs ({sweep.n_points} grid points x replicas), "
                f"over this service's limit of {limits.max_sweep_runs}")], numbers)
    runs = sweep.expand()
    agent_steps = sum(r.scenario.n_agents * r.scenario.time.steps for r in runs)
    if agent_steps > limits.max_sweep_agent_steps:
        raise SweepLimitError([FieldError(
            loc="axes", type="limit_exceeded",
            msg=f"the sweep's {n_runs} runs total {agent_steps} agent-steps (N x steps), "
                f"over this service's limit of {limits.max_sweep_agent_steps}")],
            {**numbers, "agent_steps": agent_steps})
    errors = []
    for run in runs:
        errors += [FieldError(loc=f"runs[{run.index}].{e.loc}", type=e.type,
                              msg=f"{e.msg} (run {run.index})")
                   for e in check_limits(run.scenario, limits)]
        if len(errors) >= MAX_REPORTED:
            break
    if errors:
        raise SweepLimitError(errors, {**numbers, "agent_steps": agent_steps})
    return runs
