"""One admission function for both kinds: what `admit` keeps of a run and of a sweep, and
what it refuses, checked against numbers worked out by hand."""

import pytest

from flocklab.schemas import Scenario, get_preset
from flocklab.schemas.sweep import Sweep
from flocklab.service.jobs.admission import Admitted, LimitError, admit
from flocklab.service.jobs.limits import Limits


def _base() -> dict:
    """The Vicsek 1995 preset, small: N = 100 for 50 steps, no frames recorded."""
    spec = get_preset("vicsek-1995").model_dump(mode="json")
    spec["initial"]["N"], spec["time"]["steps"] = 100, 50
    spec["recording"] = {"every": 0, "observables_every": 10}
    return spec


ROOMY = Limits(max_agents=10_000, max_steps=10_000, max_trajectory_bytes=2**30,
               max_memory_bytes=2**34)


def _sweep(**extra: object) -> Sweep:
    return Sweep.model_validate({
        "name": "n-scan", "base": _base(), "replicas": 2,
        "axes": [{"path": "initial.N", "values": [100, 300, 200]}],
        "measure": {"va": {"observable": "polarization", "reduce": "mean"}}, **extra})


def test_a_run_is_kept_as_its_model_agents_and_steps():
    assert admit(Scenario.model_validate(_base()), ROOMY) == Admitted("vicsek", 100, 50)


def test_a_sweep_is_kept_as_its_largest_run_and_its_run_count():
    # 3 grid points x 2 replicas = 6 runs; the largest N is 300.
    assert admit(_sweep(), ROOMY) == Admitted("vicsek", 300, 6)


def test_a_run_over_a_limit_names_the_field():
    with pytest.raises(LimitError) as caught:
        admit(Scenario.model_validate(_base()), Limits(50, 10_000, 2**30, 2**34))
    assert [e.loc for e in caught.value.errors] == ["initial.N"]
    assert caught.value.numbers == {}
    assert str(caught.value).startswith("initial.N: N = 100 exceeds")


def test_a_sweep_over_the_agent_steps_limit_says_its_numbers():
    # (100 + 300 + 200) x 2 replicas x 50 steps = 60,000 agent-steps.
    limits = Limits(10_000, 10_000, 2**30, 2**34, max_sweep_agent_steps=59_999)
    with pytest.raises(LimitError) as caught:
        admit(_sweep(), limits)
    assert caught.value.numbers == {"runs": 6, "max_runs": 100_000,
                                    "max_agent_steps": 59_999, "agent_steps": 60_000}


def test_a_sweep_run_over_a_per_job_limit_names_the_run():
    with pytest.raises(LimitError) as caught:
        admit(_sweep(), Limits(250, 10_000, 2**30, 2**34))
    # Runs are grid point x replica: the N = 300 point's two replicas are runs 2 and 3.
    assert [e.loc for e in caught.value.errors] == ["runs[2].initial.N", "runs[3].initial.N"]
