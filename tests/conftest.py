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
    """Run the test on both schedules: `kernels.run` and `kernels.run_batch` take
    `path=<param>` (a scenario the fused schedule does not cover skips) and every result
    must say it ran there."""
    from flocklab import kernels
    from flocklab.kernels import engine

    def run(*args, **kw):
        try:
            res = engine.run(*args, path=request.param, **kw)
        except engine.PathUnavailable as exc:
            pytest.skip(str(exc))
        assert res.extra["engine_path"] == request.param
        return res

    def run_batch(*args, **kw):
        try:
            out = engine.run_batch(*args, path=request.param, **kw)
        except engine.PathUnavailable as exc:
            pytest.skip(str(exc))
        assert {r.extra["engine_path"] for r in out} <= {request.param}
        return out

    monkeypatch.setattr(kernels, "run", run)
    monkeypatch.setattr(kernels, "run_batch", run_batch)
    return request.param


@pytest.fixture
def fixed_windows(monkeypatch):
    """Make the fused driver's windows a fixed number of agent-steps (instead of ~0.1 s
    of work), so a test can cut a run at known steps."""
    from flocklab.kernels import driver

    def fix(agent_steps: int) -> None:
        monkeypatch.setattr(driver, "WINDOW_AGENT_STEPS", agent_steps)
        monkeypatch.setattr(driver, "WINDOW_SECONDS", None)

    return fix
