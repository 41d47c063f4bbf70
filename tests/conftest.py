import os

import pytest

os.environ.setdefault("TI_LOG_LEVEL", "warn")
# Taichi's offline cache keeps 100 MB by default and evicts the least recently used quarter
# beyond it: the worktrees on one machine outgrow that and recompile each other's kernels
# cold (seconds each). Workers and CLI children inherit the setting.
os.environ.setdefault("TI_OFFLINE_CACHE_MAX_SIZE_OF_FILES", str(2**31 - 1))


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


# The lanes. The default `python -m pytest` is the fast lane, what a developer runs between
# edits; `--all` (the README's test command, .ci/run) adds the slow lanes: tests marked
# `slow` (large N, long integrations, kill-and-resume), `ray` (a real two-node cluster) and
# everything under tests/e2e/ (fresh installs, the container, the browser, schemathesis).
SLOW_LANES = ("slow", "ray", "e2e")


def pytest_configure(config):
    config.addinivalue_line(
        "markers", "slow_cases(*ids): the listed parametrised cases of this test (their ids, "
        "as in test_x[id]) are in the slow lane; the others stay in the fast one")


def pytest_addoption(parser):
    parser.addoption("--all", action="store_true",
                     help="run every lane: the fast one and the slow, ray and e2e tests")


def pytest_collection_modifyitems(config, items):
    e2e = config.rootpath / "tests" / "e2e"
    for item in items:
        if e2e in item.path.parents:
            item.add_marker(pytest.mark.e2e)
        if _slow_case(item):
            item.add_marker(pytest.mark.slow)
    if config.getoption("--all") or config.getoption("markexpr"):
        return  # everything, or the lanes a -m expression names
    keep = [it for it in items if not any(it.get_closest_marker(m) for m in SLOW_LANES)]
    if len(keep) < len(items):
        config.hook.pytest_deselected(items=[it for it in items if it not in keep])
        items[:] = keep


def pytest_report_header(config):
    if not (config.getoption("--all") or config.getoption("markexpr")):
        return "lane: fast (the slow, ray and e2e tests are left out: --all runs them)"
    return None


def _slow_case(item: pytest.Item) -> bool:
    """Whether `item` is one of the cases its `slow_cases` marker names: the heavy twins of
    a parametrised test (large N, long runs, a second schedule of the same long run), whose
    cheaper cases keep the behaviour in the fast lane."""
    marker = item.get_closest_marker("slow_cases")
    callspec = getattr(item, "callspec", None)
    return marker is not None and callspec is not None and callspec.id in marker.args
