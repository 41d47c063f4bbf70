"""A real two-node Ray cluster on this machine, on loopback only, for tests and benchmarks.

`LocalRayCluster(tmp)` starts a head (`ray start --head`) and a second node
(`ray start --address`), each with its own small CPU count and object store, no dashboard
and no usage stats, under a temp dir of its own. `stop()` ends exactly this cluster's
processes: those whose command line names its temp dir, and their descendants (the
workers and agents the raylets spawned). Never `ray stop`, which would end every Ray
cluster on the machine, another engineer's included.

`RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0` makes Ray keep every address on 127.0.0.1 and bind
its ports there only (without it `--node-ip-address 127.0.0.1` and `--address 127.0.0.1:P`
are rewritten to the machine's routable address, and the ports listen on every interface).
In that mode `ray start --address` refuses to add a node (a check meant for laptops), so
the second node's `ray start` runs through `_SECOND_NODE`, which lifts only that check.
"""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

RAY_ENV = {
    "RAY_USAGE_STATS_ENABLED": "0",
    "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0",  # loopback addresses only
}


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


# `ray start`, with the CLI's own "multi-node clusters are off" refusal lifted (the rest of
# Ray, the address resolution included, still sees clusters off and keeps to loopback).
_SECOND_NODE = """
import ray._private.ray_constants as constants
import ray.scripts.scripts as scripts

class _Constants:
    def __getattr__(self, name):
        return True if name == "ENABLE_RAY_CLUSTER" else getattr(constants, name)

scripts.ray_constants = _Constants()
scripts.main()
"""


def _ray_bin() -> str:
    return str(Path(sys.executable).with_name("ray"))


def _processes() -> dict[int, tuple[int, str]]:
    """pid -> (parent pid, command line) of every process, from Linux /proc."""
    out: dict[int, tuple[int, str]] = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            stat = Path(f"/proc/{entry}/stat").read_text()
            cmd = Path(f"/proc/{entry}/cmdline").read_bytes().replace(b"\0", b" ").decode(
                errors="replace")
        except OSError:
            continue
        out[int(entry)] = (int(stat.rsplit(")", 1)[1].split()[1]), cmd)
    return out


class LocalRayCluster:
    """Two Ray nodes on 127.0.0.1 (the head and one more), started and stopped by us."""

    def __init__(self, cpus_head: int = 1, cpus_node: int = 1,
                 object_store_bytes: int = 100 * 2**20):
        # A short temp dir: Ray's socket paths must stay under the 107-byte limit.
        self.temp_dir = Path(tempfile.mkdtemp(prefix="flray-", dir="/tmp"))
        self.port = _free_port()
        self.address = f"127.0.0.1:{self.port}"
        self.cpus_head, self.cpus_node = cpus_head, cpus_node
        self.object_store_bytes = object_store_bytes
        self.env = {**os.environ, **RAY_ENV}

    def _start(self, *args: str, head: bool, timeout: float = 90.0) -> None:
        ray = [_ray_bin()] if head else [sys.executable, "-c", _SECOND_NODE]
        cmd = [*ray, "start", *args, "--node-ip-address=127.0.0.1",
               f"--object-store-memory={self.object_store_bytes}",
               f"--temp-dir={self.temp_dir}", "--disable-usage-stats"]
        res = subprocess.run(cmd, env=self.env, capture_output=True, text=True,
                             timeout=timeout)
        if res.returncode != 0:
            raise RuntimeError(f"{' '.join(cmd)} failed:\n{res.stdout}\n{res.stderr}")

    def start(self) -> LocalRayCluster:
        try:
            self._start("--head", f"--port={self.port}", f"--num-cpus={self.cpus_head}",
                        "--include-dashboard=false", "--resources={\"head\": 1}", head=True)
            self.start_second_node()
        except BaseException:
            self.stop()
            raise
        return self

    def start_second_node(self) -> None:
        self._start(f"--address={self.address}", f"--num-cpus={self.cpus_node}",
                    "--resources={\"second\": 1}", head=False)

    def pids(self, match: str = "") -> list[int]:
        """Our processes (command line names our temp dir, or a descendant of one);
        with `match`, only those whose command line also holds it."""
        procs = _processes()
        me = {os.getpid(), os.getppid()}  # a command line naming the dir is not the cluster
        ours = {pid for pid, (_, cmd) in procs.items()
                if str(self.temp_dir) in cmd and pid not in me}
        grew = True
        while grew:
            kids = {pid for pid, (ppid, _) in procs.items() if ppid in ours} - ours
            grew = bool(kids)
            ours |= kids
        return sorted(p for p in ours if match in procs[p][1])

    def second_node_pids(self) -> list[int]:
        """The second node's raylet and everything under it (its workers)."""
        procs = _processes()
        roots = {pid for pid, (_, cmd) in procs.items()
                 if str(self.temp_dir) in cmd and "raylet" in cmd and "raylet.1" in cmd}
        ours = set(roots)
        grew = True
        while grew:
            kids = {pid for pid, (ppid, _) in procs.items() if ppid in ours} - ours
            grew = bool(kids)
            ours |= kids
        return sorted(ours)

    def stop(self, timeout: float = 10.0) -> None:
        """SIGTERM then SIGKILL every process of this cluster (and nothing else)."""
        for sig in (signal.SIGTERM, signal.SIGKILL):
            pids = self.pids()
            for pid in pids:
                with contextlib.suppress(OSError):
                    os.kill(pid, sig)
            deadline = time.monotonic() + timeout / 2
            while self.pids() and time.monotonic() < deadline:
                time.sleep(0.2)
        with contextlib.suppress(OSError):
            subprocess.run(["rm", "-rf", str(self.temp_dir)], timeout=30, check=False)

    def __enter__(self) -> LocalRayCluster:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
