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


@pytest.fixture(scope="session")
def server(tmp_path_factory: pytest.TempPathFactory):
    """One shared service for the service and client tests that need no special settings:
    the real app, store and workers in this process (tests/service/inproc.py). One for the
    session: its workers start, import Taichi and compile a job's kernels once."""
    from tests.service.conftest import TEST_ENV
    from tests.service.inproc import InProcessServer

    s = InProcessServer(tmp_path_factory.mktemp("shared") / "data", TEST_ENV).start()
    try:
        yield s
    finally:
        s.stop()


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
    config.addinivalue_line(
        "markers", "resets_taichi: the test re-initialises Taichi (float32, another thread "
        "count), which discards every kernel compiled in this process: it runs after the "
        "others")
    config.addinivalue_line(
        "markers", "fast_cases(*ids): only the listed parametrised cases of this test stay "
        "in the fast lane; the others are in the slow one (a large grid's covering subset)")


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
    _resetting_last(items)
    if config.getoption("--all") or config.getoption("markexpr"):
        return  # everything, or the lanes a -m expression names
    keep = [it for it in items if not any(it.get_closest_marker(m) for m in SLOW_LANES)]
    if len(keep) < len(items):
        config.hook.pytest_deselected(items=[it for it in items if it not in keep])
        items[:] = keep


def _resetting_last(items: list[pytest.Item]) -> None:
    """Run the `resets_taichi` tests last (in their order): a float64 kernel compiled once
    (seconds) then serves every test that uses it, instead of compiling again after each
    switch of precision or thread count (`runtime.ensure` resets Taichi)."""
    resetting = [it for it in items if it.get_closest_marker("resets_taichi")]
    if resetting:
        ids = {id(it) for it in resetting}
        items[:] = [it for it in items if id(it) not in ids] + resetting


def pytest_report_header(config):
    if not (config.getoption("--all") or config.getoption("markexpr")):
        return "lane: fast (the slow, ray and e2e tests are left out: --all runs them)"
    return None


def _slow_case(item: pytest.Item) -> bool:
    """Whether `item` is one of the cases its `slow_cases` marker names, or one its
    `fast_cases` marker leaves out: the heavy twins of a parametrised test (large N, long
    runs, a second schedule of the same long run, the rest of a large grid once every value
    of each parameter has a fast case), whose cheaper cases keep the behaviour in the fast
    lane. Each Taichi kernel variant compiles once per process (seconds), so the fast lane
    keeps few variants per test."""
    callspec = getattr(item, "callspec", None)
    if callspec is None:
        return False
    slow = item.get_closest_marker("slow_cases")
    if slow is not None and callspec.id in slow.args:
        return True
    fast = item.get_closest_marker("fast_cases")
    return fast is not None and callspec.id not in fast.args


@pytest.hookimpl(hookwrapper=True)
def pytest_generate_tests(metafunc: pytest.Metafunc):
    """A `slow_cases` / `fast_cases` id that names no case of its test is a typo (which
    would move a whole grid to the slow lane unseen): stop the collection."""
    yield
    ids = {c.id for c in getattr(metafunc, "_calls", [])}
    for name in ("slow_cases", "fast_cases"):
        for marker in metafunc.definition.iter_markers(name):
            unknown = set(marker.args) - ids
            if ids and unknown:
                raise pytest.UsageError(
                    f"{metafunc.definition.nodeid}: {name} names no case {sorted(unknown)}")
