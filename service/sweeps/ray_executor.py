"""The Ray executor: a sweep's runs (or a service job) as Ray tasks on a cluster.

This process is the Ray *driver*: it connects (`ray.init(address=...)`), submits tasks
(bodies in ray_tasks.py) and waits for them; it never initialises Taichi. Each task runs
a chunk of consecutive runs through `kernels.run_batch`, so the per-task overhead is
shared by many runs and replicas still fuse into one launch; chunks are cut from the
runner's lazy feed of runs as earlier tasks end (a window of IN_FLIGHT_PER_SLOT tasks per
slot), so the driver never holds a 10^5-run sweep's runs at once; results (observables, never
frames) come back through Ray's object store and are recorded here, by the caller, so the
journal and tables are written by one process only, exactly as with the local executor.
Runs with checkpoints run one by one in their task, each checkpointing under the sweep's
folder (run_checkpoints.py), so a task Ray retries goes on with them from there.

Failure handling:
- A task whose worker process or node dies is retried once by Ray (`max_retries=1`; on
  another node if its node is gone); application errors are not retried (R9). A chunk lost
  twice raises ClusterTaskLost; the runs recorded before it are kept (a rerun resumes).
- should_stop() -> `ray.cancel` of every outstanding task (KeyboardInterrupt between
  engine steps), then `ray.cancel(force=True)` (the worker process is killed) for those
  still running after the grace period. Runs that finished before are still recorded.
- Cannot connect -> ClusterUnavailable naming the address. Losing the cluster mid-sweep
  -> ClusterTaskLost naming it, once no task has finished for HEALTH_SECONDS and the
  cluster does not answer.
If this driver process dies, Ray ends its tasks itself (their owner is gone).
"""

from __future__ import annotations

import contextlib
import itertools
import math
import socket
import time
from collections.abc import Callable, Iterable, Iterator, Sequence, Sized
from pathlib import Path
from typing import TYPE_CHECKING, Any

from flocklab.schemas import Scenario
from flocklab.schemas.sweep import SweepRun

from . import ray_tasks
from .executors import BATCH_RUNS, ExecutorConfig, ResultFn, StopFn
from .run_checkpoints import ResumedFn

if TYPE_CHECKING:
    from flocklab.kernels import RunResult

CONNECT_SECONDS = 5.0  # a cluster address that does not accept a connection in this is down
WAIT_SECONDS = 0.2  # how often should_stop is asked while tasks run
HEALTH_SECONDS = 5.0  # silence after which the driver checks that the cluster is there
PROBE_COPIES = 64  # at most this many workers are warmed by the probe (see probe)
CHUNKS_PER_CPU = 4  # a sweep is cut into about this many tasks per cluster CPU
IN_FLIGHT_PER_SLOT = 2  # tasks submitted at once per slot: each busy, the next queued

_connected: str | None = None  # the address this process's driver is connected to


class ClusterError(RuntimeError):
    """Something about the Ray cluster at `address` (the message names it)."""

    def __init__(self, address: str, message: str):
        super().__init__(message)
        self.address = address


class ClusterUnavailable(ClusterError):
    """The cluster cannot be reached (or Ray is not installed)."""


class ClusterTaskLost(ClusterError):
    """A task failed for the cluster's reasons (worker or node lost twice, cluster gone)."""


def _ray() -> Any:
    try:
        import ray
    except ImportError:
        raise ClusterUnavailable("", "the ray executor needs Ray: pip install "
                                 "'flocklab[ray]'") from None
    return ray


def connect(address: str) -> Any:
    """The `ray` module, connected to the cluster at `address` (once per process)."""
    global _connected
    ray = _ray()
    if ray.is_initialized():
        if _connected == address:
            return ray
        ray.shutdown()
    _reachable(address)
    try:
        ray.init(address=address, log_to_driver=False, logging_level="WARNING",
                 configure_logging=True)
    except Exception as exc:  # ConnectionError, ValueError, RuntimeError, by version
        _connected = None
        raise ClusterUnavailable(address, f"cannot connect to the Ray cluster at "
                                 f"{address}: {type(exc).__name__}: {exc}") from None
    _connected = address
    _errors_to_stderr()
    return ray


def _errors_to_stderr() -> None:
    """Ray's driver prints the cluster's error messages ("a worker died ...") on stdout,
    which is the CLI's machine-readable channel (one JSON line): send them to stderr."""
    from ray._private import worker

    original = getattr(worker, "print_to_stdstream", None)
    if original is None or getattr(original, "_flocklab", False):
        return

    def to_stderr(data: dict[str, Any], ignore_prefix: bool) -> None:
        original({**data, "is_err": True}, ignore_prefix)

    to_stderr._flocklab = True  # type: ignore[attr-defined]
    worker.print_to_stdstream = to_stderr


def _reachable(address: str, timeout: float = CONNECT_SECONDS) -> None:
    """ClusterUnavailable unless host:port (or ray://host:port) accepts a TCP connection:
    `ray.init` retries an unreachable address for ever, so it is checked first."""
    if address == "auto":
        return  # Ray finds the local cluster itself and fails at once without one
    host, _, port = address.removeprefix("ray://").rpartition(":")
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=timeout).close()
    except ValueError:
        raise ClusterUnavailable(address, f"not a Ray cluster address: {address!r} (use "
                                 "auto, host:port or ray://host:port)") from None
    except OSError as exc:
        raise ClusterUnavailable(address, f"cannot connect to the Ray cluster at {address}: "
                                 f"{exc.strerror or exc}") from None


def disconnect() -> None:
    """Drop this process's connection (after the cluster was lost: reconnect next time)."""
    global _connected
    ray = _ray()
    with contextlib.suppress(Exception):
        ray.shutdown()
    _connected = None


def _resources(scenarios: Sequence[Scenario], threads: int) -> dict[str, Any]:
    """What a task reserves: CPUs = the threads its runs use; one GPU for a GPU backend."""
    cpus = max(s.threads or threads for s in scenarios)
    gpus = 1 if any(s.backend in ("cuda", "vulkan") for s in scenarios) else 0
    return {"num_cpus": cpus, "num_gpus": gpus}


class RayExecutor:
    """Runs sweeps' runs and jobs as tasks on the Ray cluster at `config.ray_address`."""

    def __init__(self, config: ExecutorConfig):
        self.config = config
        self.address = config.ray_address or "auto"
        self._remote: dict[str, Any] = {}

    def _task(self, fn: Callable[..., Any]) -> Any:
        ray = connect(self.address)
        if fn.__name__ not in self._remote:
            self._remote[fn.__name__] = ray.remote(
                max_retries=1, retry_exceptions=False, max_calls=self.config.max_calls)(fn)
        return self._remote[fn.__name__]

    def slots(self) -> int:
        """Tasks the cluster runs at once: its CPUs over the threads of a task."""
        ray = connect(self.address)
        cpus = int(ray.cluster_resources().get("CPU", 1))
        return max(1, cpus // max(1, self.config.threads))

    def chunk_size(self, n_runs: int) -> int:
        """Runs per task: enough tasks to keep every CPU busy and the progress moving,
        at most BATCH_RUNS (the engine's batch, which bounds a task's memory)."""
        return max(1, min(BATCH_RUNS, math.ceil(n_runs / (CHUNKS_PER_CPU * self.slots()))))

    # -- the Executor protocol ------------------------------------------------------------

    def run_sweep_runs(self, runs: Iterable[SweepRun], keep: str, out_dir: Path,
                       on_result: ResultFn, should_stop: StopFn,
                       on_resumed: ResumedFn | None = None) -> None:
        """Chunks of consecutive runs are taken from `runs` as tasks end, at most
        IN_FLIGHT_PER_SLOT tasks per slot submitted at once, so the driver holds a window
        of runs bounded by the cluster's size, not the sweep's. A task cannot call back
        before it ends: a run that went on from its checkpoint says so in its result's
        extra (`resumed_from_step`), which the runner reports (`on_resumed` is not called
        here)."""
        feed = iter(runs)
        head = next(feed, None)
        if head is None:
            return
        task = self._task(ray_tasks.run_chunk)
        size = self.chunk_size(len(runs)) if isinstance(runs, Sized) else BATCH_RUNS
        chunks = _chunks(itertools.chain([head], feed), size)

        def submit() -> tuple[Any, list[SweepRun]] | None:
            chunk = next(chunks, None)
            if chunk is None:
                return None
            opts = _resources([r.scenario for r in chunk], self.config.threads)
            return task.options(**opts).remote(chunk, keep, str(out_dir),
                                               self.config.threads), chunk

        def done(chunk: list[SweepRun], value: list[tuple[int, RunResult]]) -> None:
            for i, result in value:
                on_result(chunk[i], result)

        self._drive({}, done, should_stop, submit, IN_FLIGHT_PER_SLOT * self.slots())

    def probe(self, scenario: Scenario) -> RunResult:
        """The probe runs on every slot of the cluster at once and the first answer is
        used: the copies start a worker process per CPU (Taichi initialised, the
        scenario's kernels loaded) while the first answers, instead of each worker
        starting only when the sweep's tasks reach it (a new driver gets new workers)."""
        task = self._task(ray_tasks.probe)
        opts = _resources([scenario], self.config.threads)
        refs = [task.options(**opts).remote(scenario, self.config.threads)
                for _ in range(min(self.slots(), PROBE_COPIES))]
        got: list[RunResult] = []
        self._drive({refs[0]: None}, lambda _, value: got.append(value), lambda: False)
        return got[0]

    def run_job(self, scenario: Scenario, out_dir: Path, *,
                on_progress: Callable[[int, int], None] | None,
                should_stop: StopFn) -> dict[str, Any]:
        """One job as one task; progress is reported when it ends (a task has no channel
        back before that). A cancelled job returns status "cancelled"."""
        task = self._task(ray_tasks.run_job)
        ref = task.options(**_resources([scenario], self.config.threads)).remote(
            scenario, str(out_dir), self.config.threads)
        got: list[dict[str, Any]] = []
        self._drive({ref: None}, lambda _, value: got.append(value), should_stop)
        if not got:
            return {"status": "cancelled"}
        if on_progress is not None:
            on_progress(got[0].get("steps", 0), scenario.time.steps)
        return got[0]

    # -- waiting --------------------------------------------------------------------------

    def _drive(self, pending: dict[Any, Any], done: Callable[[Any, Any], None],
               should_stop: StopFn,
               submit: Callable[[], tuple[Any, Any] | None] | None = None,
               window: int = 0) -> None:
        """Wait for every task of `pending` (ref -> what `done` gets back with the value),
        and for those `submit()` starts (ref, what done gets; None: no more) while fewer
        than `window` are pending, cancelling them all once should_stop() is true."""
        from ray import exceptions as rx

        ray = connect(self.address)
        cancel_at: float | None = None  # when the cooperative cancel was sent
        forced = False
        last_news = time.monotonic()

        def top_up() -> None:
            nonlocal submit
            while submit is not None and cancel_at is None and len(pending) < window:
                item = submit()
                if item is None:
                    submit = None
                else:
                    pending[item[0]] = item[1]

        try:
            top_up()
            while pending:
                try:
                    ready, _ = ray.wait(list(pending), num_returns=len(pending),
                                        timeout=WAIT_SECONDS, fetch_local=True)
                except rx.RayError as exc:
                    # The cluster going down mid-call (this driver's raylet first, say)
                    # makes Ray raise from its own machinery: an uncaught Ray error would
                    # end the driver only after Ray's hook waited a minute for the GCS.
                    raise ClusterTaskLost(self.address, f"lost the Ray cluster at "
                                          f"{self.address} mid-run ({_first_line(exc)})"
                                          ) from None
                for ref in ready:
                    meta = pending.pop(ref)
                    value = self._value(ray, ref, stopping=cancel_at is not None)
                    if value is not _CANCELLED:
                        done(meta, value)
                top_up()
                now = time.monotonic()
                if ready:
                    last_news = now
                elif now - last_news >= HEALTH_SECONDS:
                    self._check_alive(ray)
                    last_news = now
                if cancel_at is None and should_stop():
                    cancel_at = now
                    for ref in pending:
                        with contextlib.suppress(Exception):
                            ray.cancel(ref, force=False)
                elif (cancel_at is not None and not forced
                      and now - cancel_at >= self.config.cancel_grace_seconds):
                    forced = True  # the tasks ignored KeyboardInterrupt: kill their workers
                    for ref in pending:
                        with contextlib.suppress(Exception):
                            ray.cancel(ref, force=True)
                elif forced and now - cancel_at >= self.config.cancel_grace_seconds + 30:
                    return  # the cluster never confirmed: nothing of these is recorded
        except BaseException:
            # Leaving early (an error, a second Ctrl-C): nothing may keep running for us.
            for ref in pending:
                with contextlib.suppress(Exception):
                    ray.cancel(ref, force=True)
            raise

    def _value(self, ray: Any, ref: Any, *, stopping: bool) -> Any:
        """A finished task's value; _CANCELLED for a cancelled one; errors translated."""
        from ray import exceptions as rx

        try:
            return ray.get(ref)
        except rx.TaskCancelledError:
            return _CANCELLED
        except rx.RayTaskError as exc:  # the task itself raised: not retried (R9)
            cause = exc.cause if isinstance(exc.cause, BaseException) else None
            if isinstance(cause, KeyboardInterrupt) and stopping:
                return _CANCELLED
            if cause is not None and not isinstance(cause, KeyboardInterrupt):
                raise cause from None  # e.g. BackendUnavailable, as the local executor
            raise ClusterTaskLost(self.address, f"a Ray task failed on the cluster at "
                                  f"{self.address}: {exc}") from None
        except rx.RayError as exc:  # a worker, a node, an object or the raylet lost
            if stopping:
                return _CANCELLED  # a force-cancelled task's worker was killed by us
            self._check_alive(ray)  # the whole cluster gone: say so
            raise ClusterTaskLost(
                self.address, f"a Ray task was lost on the cluster at {self.address} after "
                f"its retry ({_first_line(exc)})") from None

    def _check_alive(self, ray: Any) -> None:
        """ClusterTaskLost when the cluster's head no longer accepts connections. (Asked
        through Ray, a lost head blocks the call for a minute, after which Ray ends this
        process: so the driver probes the head's port itself.)"""
        try:
            gcs = ray.get_runtime_context().gcs_address
        except Exception:
            gcs = self.address
        try:
            _reachable(gcs)
        except ClusterUnavailable as exc:
            global _connected
            _connected = None  # reconnect on the next use; the old session is dead
            raise ClusterTaskLost(self.address, f"lost the Ray cluster at {self.address} "
                                  f"mid-run: its head ({gcs}) does not answer") from exc


def _chunks(runs: Iterator[SweepRun], size: int) -> Iterator[list[SweepRun]]:
    """Consecutive runs, `size` at a time (the last chunk may be shorter)."""
    while chunk := list(itertools.islice(runs, size)):
        yield chunk


def _first_line(exc: BaseException) -> str:
    return f"{type(exc).__name__}: {(str(exc).splitlines() or [''])[0]}"


_CANCELLED = object()
