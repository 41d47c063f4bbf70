"""The issue-28 loopback attack, repeated against a real `flocklab serve` on 127.0.0.1: the
figures its closing note asks for.

1. A sweep of the maximum size (100,000 runs: 1000 grid points x 100 replicas) admitted
   and run for `--seconds`: peak RSS (VmHWM) of the API and of the worker, the worker's
   RSS and thread count sampled as runs finish (flat: the runs are expanded lazily and
   each is written out when it ends), then cancelled.
2. The 1.1 MB body of 28,000 axes: the time to its 422.
3. One client (source 127.0.0.2) opening `--hold` connections with headers it never
   finishes: the time another client (127.0.0.3) takes to get `/healthz`.

Run: python bench/sweep_attack.py [--seconds 90] [--hold 300] [--parts many_axes,healthz,sweep]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import resource
import signal
import socket
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import httpx

from flocklab.service.serve import ServerProcess


def status_kib(pid: int, field: str) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1])
    raise KeyError(field)


def mib(pid: int, field: str) -> float:
    return status_kib(pid, field) / 1024


def threads(pid: int) -> int:
    return len(list(Path(f"/proc/{pid}/task").iterdir()))


def worker_pid(server: ServerProcess) -> int:
    for pid in server.children():
        if b"spawn_main" in Path(f"/proc/{pid}/cmdline").read_bytes():
            return pid
    raise RuntimeError("no worker process")


def max_sweep(points: int = 1000, replicas: int = 100) -> dict[str, Any]:
    return {
        "name": "max-size",
        "base": {"model": {"kind": "vicsek", "rule": "vicsek", "v0": 0.03},
                 "space": {"kind": "periodic", "L": 2.0}, "neighbours": {"radius": 1.0},
                 "initial": {"kind": "random", "N": 16}, "time": {"steps": 20},
                 "recording": {"every": 0, "observables_every": 10}, "seed": 1},
        "axes": [{"path": "model.eta", "values": [round(5 * i / points, 6)
                                                  for i in range(points)]}],
        "replicas": replicas,
        "measure": {"va": {"observable": "polarization", "reduce": "mean"}},
        "series": ["polarization"],
    }


def run_max_sweep(server: ServerProcess, seconds: float) -> dict[str, Any]:
    assert server.proc is not None
    api = server.proc.pid
    with httpx.Client(base_url=server.url, timeout=120) as http:
        r = http.post("/v1/sweeps", json=max_sweep())
        assert r.status_code == 202, r.text
        sweep = r.json()
        worker = worker_pid(server)
        samples = []
        t0 = time.monotonic()
        while time.monotonic() - t0 < seconds:
            view = http.get(f"/v1/sweeps/{sweep['id']}").json()
            samples.append((round(time.monotonic() - t0, 1), view.get("runs_done", 0),
                            round(mib(worker, "VmRSS")), round(mib(worker, "VmHWM")),
                            threads(worker)))
            # On stderr as it goes: what was seen survives a bench stopped early.
            print("sample (s, runs_done, worker RSS, HWM MiB, threads):", samples[-1],
                  "API HWM MiB:", round(mib(api, "VmHWM")), file=sys.stderr, flush=True)
            if view["status"] not in ("queued", "running"):
                break
            time.sleep(1.0)
        running_peak = round(mib(worker, "VmHWM"))
        http.post(f"/v1/sweeps/{sweep['id']}/cancel")
        view = http.get(f"/v1/sweeps/{sweep['id']}", params={"wait": 30}).json()
        return {"status_after_cancel": view["status"], "worker_peak_running_mib": running_peak,
                "runs_total": sweep["runs_total"], "body_bytes": len(json.dumps(max_sweep())),
                "api_peak_mib": round(mib(api, "VmHWM")),
                "worker_peak_mib": round(mib(worker, "VmHWM")),
                "worker_max_threads": max(s[4] for s in samples),
                "samples (s, runs_done, worker RSS, HWM MiB, threads)":
                    samples[::max(1, len(samples) // 8)]}


def many_axes(server: ServerProcess) -> dict[str, Any]:
    spec = max_sweep(points=2, replicas=1)
    spec["axes"] = [{"path": f"model.p{i}", "values": [1]} for i in range(28_000)]
    raw = json.dumps(spec).encode()
    with httpx.Client(base_url=server.url, timeout=120) as http:
        t0 = time.monotonic()
        r = http.post("/v1/sweeps", content=raw, headers={"Content-Type": "application/json"})
        took = time.monotonic() - t0
    return {"body_bytes": len(raw), "status": r.status_code, "seconds": round(took, 3),
            "answer_bytes": len(r.content)}


def _get(port: int, source: str, path: str) -> tuple[int, float]:
    t0 = time.monotonic()
    with socket.socket() as s:
        s.settimeout(30)
        s.bind((source, 0))
        s.connect(("127.0.0.1", port))
        s.sendall(f"GET {path} HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n".encode())
        raw = b""
        while chunk := s.recv(65536):
            raw += chunk
    return int(raw.split(b" ", 2)[1]), time.monotonic() - t0


def hold_connections(server: ServerProcess, n: int) -> dict[str, Any]:
    held = []
    refused = 0
    try:
        for _ in range(n):
            s = socket.socket()
            s.settimeout(10)
            s.bind(("127.0.0.2", 0))
            s.connect(("127.0.0.1", server.port))
            s.sendall(b"GET /healthz HTTP/1.1\r\nHost: x\r\nX-Slow: ")
            held.append(s)
        time.sleep(0.5)
        for s in held:  # what the server answered the hostile client, if anything yet
            s.setblocking(False)
            with contextlib.suppress(BlockingIOError):
                refused += s.recv(16).startswith(b"HTTP/1.1 503")
        times = []
        statuses = set()
        for _ in range(20):
            code, took = _get(server.port, "127.0.0.3", "/healthz")
            statuses.add(code)
            times.append(took)
        return {"hostile_connections": n, "hostile_refused_503": refused,
                "other_client_healthz_status": sorted(statuses),
                "other_client_healthz_median_s": round(statistics.median(times), 4),
                "other_client_healthz_max_s": round(max(times), 4)}
    finally:
        for s in held:
            s.close()


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=90.0)
    ap.add_argument("--hold", type=int, default=300)
    ap.add_argument("--parts", default="many_axes,healthz,sweep",
                    help="which parts to run, comma-separated (default all three)")
    args = ap.parse_args()
    parts = set(args.parts.split(","))
    # A `timeout` (SIGTERM) still stops the server and its worker (the finally below).
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(1))
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    resource.setrlimit(resource.RLIMIT_NOFILE, (min(hard, max(soft, args.hold + 256)), hard))
    env = {"FLOCKLAB_WARMUP_PRESET": "", "FLOCKLAB_THREADS_PER_WORKER": "1",
           "FLOCKLAB_MAX_SWEEP_RUNS": "100000", "FLOCKLAB_MAX_BODY_BYTES": str(4 * 2**20),
           "FLOCKLAB_MAX_JSON_BYTES": str(4 * 2**20)}
    with tempfile.TemporaryDirectory() as d:
        server = ServerProcess(Path(d) / "data", env=env, log_level="warning").start()
        try:
            for key, name, part in (
                    ("many_axes", "many_axes", lambda: many_axes(server)),
                    ("healthz", "healthz_while_one_client_holds_its_cap",
                     lambda: hold_connections(server, args.hold)),
                    ("sweep", "max_size_sweep", lambda: run_max_sweep(server, args.seconds))):
                if key in parts:
                    print(json.dumps({name: part()}), flush=True)
        finally:
            workers = server.children()
            server.stop()
            for pid in workers:
                with contextlib.suppress(ProcessLookupError):
                    os.kill(pid, 9)


if __name__ == "__main__":
    main()
