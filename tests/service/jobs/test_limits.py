"""Admission arithmetic: what a recorded trajectory and a run's memory are counted as."""

from flocklab.schemas import Scenario, get_preset
from flocklab.service.jobs.limits import (
    ENGINE_BASE_BYTES,
    ENGINE_BYTES_PER_AGENT,
    Limits,
    check_limits,
    estimated_memory_bytes,
    recorded_components,
    trajectory_bytes,
)


def _scenario(dimension: int, arrays: list[str], precision: str = "float64") -> Scenario:
    return Scenario.model_validate({
        "model": {"kind": "vicsek", "rule": "vicsek", "v0": 0.03, "eta": 0.5},
        "space": {"kind": "periodic", "L": 10.0, "dimension": dimension},
        "neighbours": {"radius": 1.0},
        "initial": {"kind": "random", "N": 1000},
        "time": {"steps": 99},
        "recording": {"every": 10, "arrays": arrays, "precision": precision},
    })


def _flock_3d(arrays: list[str]) -> Scenario:
    """The 3D Tanner flock (positions and velocities), recording `arrays`."""
    sc = get_preset("tjp-switching-3d")
    return sc.model_copy(update={"recording": sc.recording.model_copy(update={"arrays": arrays})})


def test_vectors_count_one_value_per_coordinate():
    assert recorded_components(_scenario(2, ["position", "heading"])) == 3
    assert recorded_components(_scenario(3, ["position", "heading"])) == 4
    assert recorded_components(_flock_3d(["position", "velocity"])) == 6
    # An array the model does not have is not recorded (Vicsek keeps no velocity).
    assert recorded_components(_scenario(3, ["position", "velocity"])) == 3


def test_trajectory_bytes_follow_dimension_precision_and_the_image():
    frames = _scenario(3, ["position"]).n_frames
    # 3 float64 coordinates + 3 int32 image entries per agent and frame.
    assert trajectory_bytes(_scenario(3, ["position"])) == frames * 1000 * (3 * 8 + 3 * 4)
    f32 = _scenario(2, ["position"], "float32")
    assert trajectory_bytes(f32) == frames * 1000 * (2 * 4 + 2 * 4)
    flock = _flock_3d(["velocity"])  # unbounded space: no image
    assert trajectory_bytes(flock) == flock.n_frames * flock.n_agents * 3 * 8


def test_memory_estimate_counts_the_engine_and_one_frame():
    sc = _flock_3d(["position", "velocity"])
    assert estimated_memory_bytes(sc) == (
        ENGINE_BASE_BYTES + sc.n_agents * (ENGINE_BYTES_PER_AGENT + 6 * 8))


def test_the_trajectory_limit_message_names_the_bytes_per_value():
    sc = _scenario(3, ["position"], "float32")
    limits = Limits(max_agents=10**6, max_steps=10**6, max_trajectory_bytes=1000,
                    max_memory_bytes=2**40)
    (err,) = [e for e in check_limits(sc, limits) if e.loc == "recording.every"]
    assert "3 values x 4 B" in err.msg
