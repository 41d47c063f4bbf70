import os

import pytest

os.environ.setdefault("TI_LOG_LEVEL", "warn")


@pytest.fixture(scope="session")
def taichi_cpu():
    """Taichi on the CPU in the test process (all engine tests run on the main thread)."""
    from flocklab.kernels import runtime

    return runtime.ensure("cpu")


@pytest.fixture(params=["fused", "per_step"])
def path(request, monkeypatch):
    """Run the test on both engine paths: the fused small-N one (where the engine takes it)
    and the per-step one (forced by lowering the fused path's size limit)."""
    from flocklab import kernels

    if request.param == "per_step":
        monkeypatch.setattr(kernels.engine, "FUSED_MAX_N", 0)
    return request.param


@pytest.fixture
def fixed_windows(monkeypatch):
    """Make the fused driver's windows a fixed number of agent-steps (instead of ~0.1 s
    of work), so a test can cut a run at known steps."""
    from flocklab.kernels import batch

    def fix(agent_steps: int) -> None:
        monkeypatch.setattr(batch, "WINDOW_AGENT_STEPS", agent_steps)
        monkeypatch.setattr(batch, "WINDOW_SECONDS", None)

    return fix
