"""The overlay geometry only the engine can build, for the run folder (worker side).

`overlays(scenario, times)` is what the renderer's data needs of the families' own helpers
(numpy only: Taichi is never imported here); service/execute.py writes it into the run
folder where the engine ran (a worker, the CLI), never in the API process nor in a drawing
process, so service/ never reaches into a family.

Returned arrays, by name (absent when the model has none):
  graph_edges     (E, 2) int64: a fixed interaction graph's edges i < j (M2, topology fixed)
  leader_path     (K, D): K samples of the virtual leader's path p(t) over the run (M4)
  leader          (F, D): p(t) at each frame time (M4)
  offsets         (S, N, D): the stored formations b_i (M4 F1) and
  offset_weights  (F, S, D, D): at frame f, b_i = sum_s offsets[s, i] @ offset_weights[f, s].T,
                  so agent i's virtual leader is r_id = leader[f] + b_i (eq. 3)
"""

from __future__ import annotations

import numpy as np

from flocklab.schemas import Scenario
from flocklab.schemas.flocking import FlockingParams
from flocklab.schemas.formation import FormationParams

PATH_SAMPLES = 400  # samples of the leader's path drawn as its line


def overlays(scenario: Scenario, times: np.ndarray) -> dict[str, np.ndarray]:
    """The engine-built overlay geometry of `scenario` at the frame `times`."""
    model = scenario.model
    if isinstance(model, FlockingParams) and model.topology == "fixed":
        return {"graph_edges": _fixed_graph(scenario)}
    if isinstance(model, FormationParams):
        return _leaders(scenario, np.asarray(times, dtype=np.float64))
    return {}


def _fixed_graph(scenario: Scenario) -> np.ndarray:
    from .models.flocking.topology import build_edges

    assert isinstance(scenario.model, FlockingParams) and scenario.model.graph is not None
    u, v = build_edges(scenario.model.graph, scenario.n_agents, scenario.seed)
    return np.column_stack([u, v]).astype(np.int64)


def _leaders(scenario: Scenario, times: np.ndarray) -> dict[str, np.ndarray]:
    """The leader's path p(t) as the run built it (from the initial centroid unless the
    path gives its start) and, for F1, the offset schedule b_i(t) at the frame times."""
    from .models.formation.path import make_path
    from .models.formation.schedule import OffsetSchedule
    from .space.initial import initial_state

    model = scenario.model
    assert isinstance(model, FormationParams)
    dim = scenario.dimension
    centroid = (initial_state(scenario).positions.mean(axis=0) if model.path.start is None
                else None)
    path = make_path(model.path, centroid)
    t_end = scenario.time.steps * scenario.time.dt
    out = {
        "leader_path": np.array([path.position(t)
                                 for t in np.linspace(0.0, t_end, PATH_SAMPLES)]),
        "leader": np.array([path.position(t) for t in times]).reshape(len(times), dim),
    }
    if model.design == "F1":
        assert model.formation is not None and scenario.neighbours is not None
        schedule = OffsetSchedule(model.formation, model.schedule, scenario.n_agents,
                                  float(scenario.neighbours.radius), dim)
        weights = np.zeros((len(times), len(schedule.stored), dim, dim))
        for f, t in enumerate(times):
            for s, m in schedule.weights(float(t)).items():
                weights[f, s] = m
        out["offsets"] = np.stack(schedule.stored)
        out["offset_weights"] = weights
    return out
