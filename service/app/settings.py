"""Service settings: defaults that work with no configuration, overridable by environment
variables `FLOCKLAB_<NAME>` or a settings file in dotenv format (`FLOCKLAB_<NAME>=value`
lines) named by `--settings` or `FLOCKLAB_SETTINGS_FILE`.

Precedence, highest first: command-line flags, environment, settings file, defaults.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Literal

from pydantic import Field, SecretStr
from pydantic_settings import BaseSettings, SettingsConfigDict

from flocklab.service.jobs import Limits, SupervisorConfig
from flocklab.service.sweeps.executors import ExecutorConfig

MiB = 2**20
GiB = 2**30


def default_data_dir() -> Path:
    """$XDG_DATA_HOME/flocklab, else ~/.local/share/flocklab."""
    base = os.environ.get("XDG_DATA_HOME") or Path.home() / ".local" / "share"
    return Path(base) / "flocklab"


def available_cpus() -> int:
    """CPUs this process may use: the affinity mask, capped by a cgroup v2 CPU quota."""
    try:
        n = len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        n = os.cpu_count() or 1
    try:
        quota, period = Path("/sys/fs/cgroup/cpu.max").read_text().split()
        if quota != "max":
            n = min(n, max(1, math.ceil(int(quota) / int(period))))
    except (OSError, ValueError):
        pass
    return max(1, n)


class Settings(BaseSettings):
    """Everything an operator can set. Each field is `FLOCKLAB_<FIELD>` in the environment."""

    model_config = SettingsConfigDict(env_prefix="FLOCKLAB_", extra="ignore")

    data_dir: Path = Field(default_factory=default_data_dir,
                           description="Holds jobs.sqlite3, results/ and tmp/.")
    workers: int = Field(default=1, ge=1, le=256, description="Worker processes (jobs at once).")
    threads_per_worker: int | None = Field(
        default=None, ge=1, description="CPU threads per job; default: CPUs / workers.")
    max_queued: int = Field(default=64, ge=1, description="Queued jobs before 429.")
    max_body_bytes: int = Field(default=16 * MiB, ge=1024, description="Request body cap.")
    max_agents: int = Field(default=2_000_000, ge=1)
    max_steps: int = Field(default=10_000_000, ge=1)
    max_trajectory_bytes: int = Field(default=8 * GiB, ge=1)
    max_memory_bytes: int = Field(default=8 * GiB, ge=1)
    max_sweep_runs: int = Field(default=100_000, ge=1, description="Runs per sweep.")
    max_sweep_agent_steps: int = Field(default=10**12, ge=1,
                                       description="Agents x steps summed over a sweep's runs.")
    max_json_bytes: int = Field(default=32 * MiB, ge=1024,
                                description="Largest trajectory slice served as JSON.")
    job_timeout_seconds: float = Field(default=3600.0, gt=0,
                                       description="Default per-job wall-clock limit.")
    max_job_timeout_seconds: float = Field(default=24 * 3600.0, gt=0)
    cancel_grace_seconds: float = Field(default=5.0, gt=0,
                                        description="Cooperative stop, then SIGKILL.")
    lease_seconds: float = Field(default=30.0, gt=0)
    max_attempts: int = Field(default=2, ge=1,
                              description="Attempts per job; only a lost worker retries.")
    result_ttl_seconds: float = Field(default=7 * 24 * 3600.0, gt=0)
    worker_max_jobs: int = Field(default=500, ge=1, description="Recycle a worker after this.")
    worker_max_rss_bytes: int = Field(default=4 * GiB, ge=0,
                                      description="Recycle a worker above this RSS (0: never).")
    warmup_preset: str | None = Field(
        default="vicsek-1995", description="Preset run tiny at worker start ('' for none).")
    api_key: SecretStr | None = Field(
        default=None, description="When set, every route but /healthz needs it.")
    cors_origins: list[str] = Field(default_factory=list,
                                    description="Allowed CORS origins (JSON list); none: off.")
    executor: Literal["local", "ray"] = Field(
        default="local", description="Where jobs and sweeps run: the worker processes, or "
        "Ray tasks on the cluster at ray_address (the workers then only drive them).")
    ray_address: str = Field(default="auto",
                             description="The Ray cluster: auto, host:port or ray://host:port.")
    ray_threads: int = Field(default=1, ge=1,
                             description="CPU threads (num_cpus) of a Ray task.")
    ray_max_calls: int = Field(default=20, ge=1,
                               description="Tasks a Ray worker process runs before recycling.")
    # Hardening (docs/SERVICE_HARDENING.md).
    min_free_disk_bytes: int = Field(
        default=256 * MiB, ge=0, description="Free space the data disk keeps: below it, "
        "submissions get 503 and queued jobs wait (0: no check).")
    max_observable_rows: int = Field(
        default=1_000_000, ge=1, description="Rows of a job's observables series "
        "(steps / recording.observables_every) before 422.")
    max_connections: int = Field(
        default=1000, ge=1, description="Open connections before new ones get 503 (capped "
        "below the open-file limit).")
    max_connections_per_client: int = Field(
        default=64, ge=1, description="Open connections of one client (peer IP address) "
        "before its new ones get 503, so one client cannot take every connection (behind a "
        "reverse proxy every client is the proxy: raise it to max_connections there).")
    healthz_headroom: int = Field(
        default=16, ge=0, description="Connections past max_connections that are served "
        "only for GET /healthz (one request each), so a liveness probe answers when the "
        "cap is full.")
    render_cache_bytes: int = Field(
        default=1 * GiB, ge=0, description="Total size of the pictures and movies kept "
        "after drawing (all results folders): past it the least recently used are deleted.")
    render_slots: int = Field(
        default_factory=lambda: max(2, available_cpus() // 2), ge=1,
        description="Pictures drawn at once (child processes); default: half the CPUs, "
        "at least 2.")
    render_slots_per_client: int = Field(
        default=1, ge=1, description="Of those, how many one client (peer IP address) may "
        "hold; its other draws wait for its own.")
    header_timeout_seconds: float = Field(
        default=10.0, gt=0, description="A request line and headers must arrive within this "
        "(from the connection's start or its previous response), else 408 and close.")
    body_timeout_seconds: float = Field(
        default=60.0, gt=0, description="A request body must arrive within this after its "
        "headers, else 408 and close.")
    keep_alive_seconds: float = Field(
        default=5.0, gt=0, description="An idle keep-alive connection is closed after this.")

    def limits(self) -> Limits:
        return Limits(max_agents=self.max_agents, max_steps=self.max_steps,
                      max_trajectory_bytes=self.max_trajectory_bytes,
                      max_memory_bytes=self.max_memory_bytes,
                      max_observable_rows=self.max_observable_rows,
                      max_sweep_runs=self.max_sweep_runs,
                      max_sweep_agent_steps=self.max_sweep_agent_steps)

    def supervisor_config(self) -> SupervisorConfig:
        threads = self.threads_per_worker or max(1, available_cpus() // self.workers)
        return SupervisorConfig(
            workers=self.workers,
            threads_per_worker=threads,
            limits=self.limits(),
            lease_seconds=self.lease_seconds,
            max_attempts=self.max_attempts,
            cancel_grace_seconds=self.cancel_grace_seconds,
            result_ttl_seconds=self.result_ttl_seconds,
            worker_max_jobs=self.worker_max_jobs,
            worker_max_rss_bytes=self.worker_max_rss_bytes,
            # With Ray the workers are drivers: Taichi runs on the cluster, never here.
            warmup_preset=(self.warmup_preset or None) if self.executor == "local" else None,
            executor=self.executor_config(),
            min_free_bytes=self.min_free_disk_bytes,
        )

    def executor_config(self) -> ExecutorConfig:
        return ExecutorConfig(kind=self.executor, ray_address=self.ray_address,
                              threads=self.ray_threads, max_calls=self.ray_max_calls,
                              # Half the supervisor's grace: the driver force-cancels its
                              # tasks before the supervisor would kill the driver.
                              cancel_grace_seconds=self.cancel_grace_seconds / 2)


def load_settings(settings_file: str | Path | None = None, **overrides: object) -> Settings:
    """Settings from (highest first) `overrides`, the environment, the file, the defaults."""
    path = settings_file or os.environ.get("FLOCKLAB_SETTINGS_FILE")
    if path is not None and not Path(path).is_file():
        raise FileNotFoundError(f"settings file not found: {path}")
    return Settings(_env_file=path, **overrides)  # type: ignore[call-arg]
