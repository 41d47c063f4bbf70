"""Helpers of the recording.observables tests (test_flocking_observables.py,
test_formation_observables.py)."""

from typing import Any

from flocklab import kernels
from flocklab.schemas import Scenario
from tests.kernels.flocking.test_flocking_fused import Frames


def with_observables(sc: Scenario, names: list[str] | None, **recording: Any) -> Scenario:
    """The scenario with recording.observables = names (and other recording fields)."""
    doc = sc.model_dump(mode="json")
    doc["recording"].update(recording, observables=names)
    return Scenario.model_validate(doc)


def counted(monkeypatch, owner, name: str) -> list[int]:
    """Count the calls of owner.name (a module's function or a class's method), which
    still runs: calls[0] after the run."""
    calls = [0]
    real = getattr(owner, name)

    def spy(*args, **kwargs):
        calls[0] += 1
        return real(*args, **kwargs)

    monkeypatch.setattr(owner, name, spy)
    return calls


def run(sc: Scenario):
    """(result, frames) of a completed run."""
    sink = Frames()
    res = kernels.run(sc, sink=sink)
    assert res.status == "completed", res.error
    return res, sink
