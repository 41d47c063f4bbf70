"""One vocabulary of job states and one status model for both kinds of job."""

import pytest
from pydantic import Field

from flocklab.schemas.status import (
    STATES,
    TERMINAL_STATES,
    JobView,
    LifecycleView,
    SweepStatus,
)


def test_the_states_are_the_lifecycle_in_order():
    assert STATES == ("queued", "running", "succeeded", "failed", "cancelled", "timed_out")
    assert TERMINAL_STATES == ("succeeded", "failed", "cancelled", "timed_out")


def test_the_schema_enum_gives_the_viewer_the_final_states():
    # viewer.js: the states after "running" in JobView.status's enum are final.
    enum = JobView.model_json_schema()["properties"]["status"]["enum"]
    assert tuple(enum[enum.index("running") + 1:]) == TERMINAL_STATES


def test_both_views_extend_the_lifecycle_and_keep_their_wire_order():
    """The `required` lists of the OpenAPI document from before the views shared a base
    (main at d55ba63): a base's fields would otherwise come first."""
    assert issubclass(JobView, LifecycleView) and issubclass(SweepStatus, LifecycleView)
    assert JobView.model_json_schema()["required"] == [
        "id", "status", "progress", "steps_done", "steps_total", "model", "n_agents",
        "created_at", "started_at", "finished_at", "attempts", "cancel_requested", "backend",
        "timeout_seconds", "error", "results", "results_expire_at", "checksums", "links"]
    assert SweepStatus.model_json_schema()["required"] == [
        "id", "status", "progress", "runs_done", "runs_failed", "runs_total", "model",
        "created_at", "started_at", "finished_at", "attempts", "cancel_requested",
        "timeout_seconds", "error", "results", "results_expire_at", "checksums", "links"]


def test_a_view_whose_wire_order_misses_a_field_is_refused():
    with pytest.raises(TypeError, match="wire_order"):
        class Partial(LifecycleView):
            wire_order = ("id",)
            extra: int = Field(default=0)
