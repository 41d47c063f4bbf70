"""`flocklab serve`: run the REST service with uvicorn."""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from types import FrameType


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="flocklab serve",
        description="Serve the flocklab job API. Settings not given here come from "
        "FLOCKLAB_* environment variables, then the settings file, then defaults.")
    p.add_argument("--host", default="127.0.0.1", help="Interface to bind (default 127.0.0.1).")
    p.add_argument("--port", type=int, default=8000, help="Port (default 8000).")
    p.add_argument("--data-dir", type=Path, help="Job store and results folder.")
    p.add_argument("--workers", type=int, help="Worker processes (jobs run at once).")
    p.add_argument("--settings", type=Path, help="Settings file (dotenv: FLOCKLAB_X=value).")
    p.add_argument("--executor", choices=["local", "ray"],
                   help="Run jobs and sweeps in local workers or as tasks on a Ray cluster.")
    p.add_argument("--ray-address", metavar="ADDR",
                   help="The Ray cluster (auto, host:port, ray://host:port).")
    p.add_argument("--log-level", default="info",
                   choices=["critical", "error", "warning", "info", "debug"])
    return p


def cli_main(argv: list[str]) -> int:
    """Parse `argv` (the arguments after `serve`), serve until interrupted, return 0."""
    args = build_parser().parse_args(argv)
    import uvicorn

    from flocklab.service.app import create_app, load_settings
    from flocklab.service.app.connections import (
        ConnectionLimits,
        connection_cap,
        guarded_protocol,
        quiet_noisy_loggers,
        raise_fd_limit,
    )
    from flocklab.service.jobs import data_dir_locked

    overrides = {k: v for k, v in (("data_dir", args.data_dir), ("workers", args.workers),
                                   ("executor", args.executor),
                                   ("ray_address", args.ray_address))
                 if v is not None}
    try:
        settings = load_settings(args.settings, **overrides)
    except (FileNotFoundError, ValueError) as exc:
        print(f"flocklab serve: {exc}", file=sys.stderr)
        return 2
    logging.basicConfig(level=args.log_level.upper(),
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    quiet_noisy_loggers()
    cap = connection_cap(settings.max_connections, raise_fd_limit(),
                         settings.healthz_headroom)
    if cap < settings.max_connections:
        logging.getLogger("flocklab.connections").warning(
            "max_connections lowered from %d to %d to stay under the open-file limit",
            settings.max_connections, cap)
    app = create_app(settings)
    protocol = guarded_protocol(ConnectionLimits(
        header_timeout=settings.header_timeout_seconds,
        body_timeout=settings.body_timeout_seconds, max_connections=cap,
        max_per_client=min(cap, settings.max_connections_per_client),
        healthz_headroom=settings.healthz_headroom))
    config = uvicorn.Config(app, host=args.host, port=args.port, log_level=args.log_level,
                            proxy_headers=False, server_header=False, http=protocol,
                            timeout_keep_alive=settings.keep_alive_seconds,
                            timeout_graceful_shutdown=10, lifespan="on")

    class Server(uvicorn.Server):
        """uvicorn's server, which on SIGTERM/SIGINT also releases long-polls and event
        streams at once, so shutdown does not wait out the grace period for them."""

        def handle_exit(self, sig: int, frame: FrameType | None) -> None:
            hub = getattr(app.state, "hub", None)
            if hub is not None:
                hub.close_threadsafe()
            super().handle_exit(sig, frame)

    try:
        Server(config).run()
    except SystemExit:
        # uvicorn exits 3 when the lifespan fails; the documented exit for a data
        # directory another service holds is 1.
        if data_dir_locked(settings.data_dir):
            print(f"flocklab serve: another flocklab service is using {settings.data_dir}",
                  file=sys.stderr)
            return 1
        raise
    return 0


class ServerProcess:
    """`flocklab serve` in a child process on 127.0.0.1: for tests and benchmarks that
    need a real server (and need to kill it)."""

    def __init__(self, data_dir: Path, *, env: dict[str, str] | None = None,
                 port: int | None = None, log_path: Path | None = None,
                 log_level: str = "info"):
        self.data_dir = Path(data_dir)
        self.log_level = log_level
        self.env = env or {}
        self.port = port or free_port()
        self.log_path = log_path or self.data_dir.with_name(self.data_dir.name + ".log")
        self.proc: subprocess.Popen[bytes] | None = None

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def start(self, timeout: float = 60.0) -> ServerProcess:
        """Start and wait until /healthz answers 200."""
        import httpx

        cmd = [sys.executable, "-m", "flocklab.service.serve", "--port", str(self.port),
               "--data-dir", str(self.data_dir), "--log-level", self.log_level]
        with self.log_path.open("ab") as log:
            self.proc = subprocess.Popen(cmd, env={**os.environ, **self.env}, stdout=log,
                                         stderr=subprocess.STDOUT)
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"server exited with {self.proc.returncode}; see "
                                   f"{self.log_path}")
            with contextlib.suppress(httpx.TransportError):
                if httpx.get(f"{self.url}/healthz", timeout=2).status_code == 200:
                    return self
            time.sleep(0.1)
        self.kill()
        raise TimeoutError(f"server not healthy after {timeout} s; see {self.log_path}")

    def children(self) -> list[int]:
        """Pids of the server's child processes (the workers), from Linux /proc."""
        if self.proc is None:
            return []
        pids = []
        for task in Path(f"/proc/{self.proc.pid}/task").glob("*"):
            with contextlib.suppress(OSError):
                pids += [int(p) for p in (task / "children").read_text().split()]
        return pids

    def stop(self, timeout: float = 20.0) -> int | None:
        """SIGTERM (graceful: running jobs are re-queued), then SIGKILL if need be."""
        if self.proc is None or self.proc.poll() is not None:
            return self.proc.returncode if self.proc else None
        self.proc.send_signal(signal.SIGTERM)
        try:
            return self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.kill()
            return None

    def kill(self) -> None:
        """SIGKILL the API process (its workers notice and exit by themselves)."""
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


if __name__ == "__main__":
    sys.exit(cli_main(sys.argv[1:]))
