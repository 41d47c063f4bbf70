"""The scenario contract: strict, complete error reports, canonical round trip."""

import json
import math

import pytest
from pydantic import ValidationError

from flocklab.schemas import MODELS, PRESETS, Scenario, field_errors, get_preset, parse_json_strict

GOOD = {
    "model": {"kind": "vicsek", "rule": "average"},
    "space": {"kind": "periodic", "L": 10},
    "neighbours": {"radius": 1},
    "initial": {"kind": "random", "N": 100},
    "time": {"steps": 10},
}


def errors(data: dict) -> dict[str, str]:
    with pytest.raises(ValidationError) as info:
        Scenario.model_validate_json(json.dumps(data))
    return {e.loc: e.msg for e in field_errors(info.value)}


def with_(path: str, value):
    data = json.loads(json.dumps(GOOD))
    *head, last = path.split(".")
    node = data
    for k in head:
        node = node.setdefault(k, {})
    node[last] = value
    return data


def test_good_scenario_round_trips_canonically():
    sc = Scenario.model_validate_json(json.dumps(GOOD))
    again = Scenario.model_validate_json(sc.model_dump_json())
    assert again == sc
    assert sc.inclusive is True  # paper 001: "in or on" the circle
    assert sc.seed == 0 and sc.backend == "cpu"


@pytest.mark.parametrize("path,value,where,fragment", [
    ("model.eta", True, "model.eta", "valid number"),
    ("model.eta", "0.1", "model.eta", "valid number"),
    ("model.eta", -1, "model.eta", "greater than or equal"),
    ("model.kind", "boids", "model", "does not match"),
    ("model.rule", "majority", "model.rule", "Input should be"),
    ("time.dt", 0, "time.dt", "greater than 0"),
    ("time.dt", -0.1, "time.dt", "greater than 0"),
    ("time.steps", 1.5, "time.steps", "valid integer"),
    ("initial.N", 0, "initial.N", "greater than 0"),
    ("initial.N", 10**9, "initial.N", "less than or equal"),
    ("time.steps", 10**9 + 1, "time.steps", "less than or equal"),
    ("recording.every", 10**9 + 1, "recording.every", "less than or equal"),
    ("recording.observables_every", 2**31, "recording.observables_every",
     "less than or equal"),
    ("space.L", 1e301, "space.L", "less than or equal"),
    ("model.rule", "laplacian", "model", "needs g > N"),
    ("model.colour", "red", "model.colour", "Extra inputs"),
    ("backend", "tpu", "backend", "Input should be"),
])
def test_bad_field_is_named(path, value, where, fragment):
    errs = errors(with_(path, value))
    assert where in errs, errs
    assert fragment in errs[where], errs


def test_every_problem_reported_at_once():
    data = with_("time.dt", 0)
    data["model"]["eta"] = True
    data["seed"] = -1
    data["extra"] = 1
    assert {"time.dt", "model.eta", "seed", "extra"} <= set(errors(data))


def test_model_cross_checks_point_at_the_model():
    errs = errors(with_("model", {"kind": "vicsek", "rule": "laplacian", "g": 100}))
    assert "g > N" in errs["model"]
    errs = errors(with_("model", {"kind": "vicsek", "rule": "average", "g": 200}))
    assert "only to rule 'laplacian'" in errs["model"]
    data = dict(GOOD)
    del data["neighbours"]
    assert "neighbours" in errors(data)["model"]


def test_recording_cap_and_plane_region():
    data = with_("recording", {"every": 1, "max_frames": 5})
    assert "max_frames" in errors(data)["(root)"]
    data = with_("space", {"kind": "plane"})
    assert "region is required" in errors(data)["(root)"]


def test_explicit_arrays_checked():
    data = with_("initial", {"kind": "explicit", "positions": [[0, 0], [1, 1]],
                             "headings": [0.1]})
    assert "headings has 1" in errors(data)["initial"]
    data = with_("initial", {"kind": "explicit", "positions": [[0, 0], [1, 2, 3]]})
    assert "positions[1] has 3 coordinates" in errors(data)["initial.positions"]


@pytest.mark.parametrize("text", ['{"a": NaN}', '{"a": Infinity}', '{"a": -Infinity}',
                                  '{"a": 1e400}'])
def test_strict_json_refuses_non_finite(text):
    with pytest.raises(ValueError):
        parse_json_strict(text)


def test_every_preset_is_valid():
    assert PRESETS
    for name in PRESETS:
        assert get_preset(name).name == name


def test_embedded_default_is_the_example():
    from pathlib import Path

    from flocklab.schemas.vicsek_presets import DEFAULT_PRESET

    example = Path(__file__).resolve().parents[2] / "examples" / "vicsek.json"
    assert Scenario.model_validate_json(example.read_text()) == get_preset(DEFAULT_PRESET)


def test_schema_and_kernel_registries_agree():
    from flocklab.kernels.model import MODULES, all_kernels

    assert set(MODELS) == set(all_kernels()) == set(MODULES)


def test_every_model_runs_reproducibly_on_every_available_backend(taichi_cpu):
    """Each registered model, through a preset of its own, cut to a few steps: the same seed
    gives the same frames bit for bit. GPU backends join when one is present."""
    import numpy as np

    from flocklab import kernels
    from flocklab.kernels import runtime

    backends = ["cpu"] + [b for b in ("cuda", "vulkan") if runtime.gpu_available(b)]
    by_kind = {}
    for name in PRESETS:
        by_kind.setdefault(get_preset(name).model.kind, name)
    assert set(by_kind) == set(MODELS), "every model needs at least one preset"

    class Keep:
        def __init__(self):
            self.frames = []

        def frame(self, step, time, arrays):
            self.frames.append(arrays)

    for kind, name in by_kind.items():
        for backend in backends:
            sc = get_preset(name)
            sc = sc.model_copy(update={
                "time": sc.time.model_copy(update={"steps": 5}),
                "recording": sc.recording.model_copy(update={"every": 1}),
                "backend": backend,
            })
            runs = []
            for _ in range(2):
                keep = Keep()
                result = kernels.run(sc, sink=keep)
                assert result.status == "completed", (kind, result.error)
                runs.append(keep.frames)
            assert len(runs[0]) == 6
            for a, b in zip(*runs, strict=True):
                for key in a:
                    assert np.array_equal(a[key], b[key]), (kind, backend, key)


def test_jittered_lattice_start_keeps_agents_apart():
    from scipy.spatial import cKDTree

    from flocklab.kernels.space.initial import initial_state

    data = with_("initial", {"kind": "random", "N": 1600, "region": {
        "kind": "lattice", "low": [1, 1], "spacing": 0.2, "jitter": 0.3}})
    sc = Scenario.model_validate(data)
    pos = initial_state(sc).positions
    d, _ = cKDTree(pos).query(pos, k=2)
    assert d[:, 1].min() >= 0.2 * (1 - 2 * 0.3) - 1e-12
    assert pos.min() >= 1 - 0.3 * 0.2 and pos.max() <= 1 + 0.2 * 39.3
    too_big = with_("initial", {"kind": "random", "N": 10_000, "region": {
        "kind": "lattice", "spacing": 0.5}})
    assert "inside the periodic box" in errors(too_big)["(root)"]
    assert "jitter" in str(errors(with_("initial", {"kind": "random", "N": 4, "region": {
        "kind": "lattice", "spacing": 0.5, "jitter": 0.5}})))


def test_vicsek_noise_above_two_pi_is_refused():
    from pydantic import ValidationError

    from flocklab.schemas.vicsek import VicsekParams

    assert VicsekParams.model_validate({"eta": 2 * math.pi}).eta == 2 * math.pi
    with pytest.raises(ValidationError, match=r"less than or equal to 6\.28"):
        VicsekParams.model_validate({"eta": 9.0})


@pytest.mark.parametrize("loc, want", [
    (("model", "vicsek", "eta"), "model.eta"),
    (("model", "formation", "formation", "offsets", 1), "model.formation.offsets.1"),
    (("initial", "random", "region", "ball", "radius"), "initial.region.radius"),
    (("space", "periodic", "L"), "space.L"),
])
def test_field_paths_drop_union_tags_but_not_fields_named_like_them(loc, want):
    from flocklab.schemas.problems import _without_union_tags

    assert ".".join(str(p) for p in _without_union_tags(loc)) == want
