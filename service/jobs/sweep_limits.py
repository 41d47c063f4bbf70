"""Admission limits of a sweep: its run count, its total agent-steps, and every expanded
run against the per-job limits. Pure Python, like `limits`: the API checks a sweep before
storing it and the worker again before running it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from flocklab.schemas import FieldError

from .limits import Limits, check_limits

if TYPE_CHECKING:
    from flocklab.schemas.sweep import Sweep

# Enough per-run errors to see the pattern; a 10^5-run sweep would flood the answer.
MAX_REPORTED = 20


class SweepLimitError(Exception):
    """A sweep over this service's limits: the field errors and the numbers behind them."""

    def __init__(self, errors: list[FieldError], numbers: dict[str, int] | None = None):
        self.errors = errors
        self.numbers = numbers or {}
        super().__init__("; ".join(f"{e.loc}: {e.msg}" for e in errors))


@dataclass(frozen=True)
class SweepScan:
    """What admitting a sweep needs of its runs, gathered in one pass over them."""

    runs: int
    agent_steps: int  # N x steps summed over the runs
    max_agents: int  # the largest N of a run
    model_kind: str  # the first run's model


def check_sweep(sweep: Sweep, limits: Limits) -> SweepScan:
    """The sweep's scan, once it is within every limit.

    The run count is checked before the runs are expanded (expanding is the costly
    part); then, in one pass over the runs expanded lazily (`Sweep.iter_runs`: memory
    does not grow with the sweep), the total agent-steps (N x steps summed over runs) and
    each run against the per-job limits, errors naming the run and the field. Raises
    SweepLimitError, or `schemas.sweep.SweepError` when a run is invalid (that first).
    """
    n_runs = sweep.n_runs
    numbers = {"runs": n_runs, "max_runs": limits.max_sweep_runs,
               "max_agent_steps": limits.max_sweep_agent_steps}
    if n_runs > limits.max_sweep_runs:
        raise SweepLimitError([FieldError(
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
        raise SweepLimitError([FieldError(
            loc="axes", type="limit_exceeded",
            msg=f"the sweep's {n_runs} runs total {agent_steps} agent-steps (N x steps), "
                f"over this service's limit of {limits.max_sweep_agent_steps}")],
            {**numbers, "agent_steps": agent_steps})
    if errors:
        raise SweepLimitError(errors[:MAX_REPORTED], {**numbers, "agent_steps": agent_steps})
    return SweepScan(count, agent_steps, max_agents, kind)
