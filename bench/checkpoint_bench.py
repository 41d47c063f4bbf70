"""Checkpoint cost per step (issue 26's bar: under 5 % at N = 10^6, every 1000 steps).

    python -m bench.checkpoint_bench                       # N = 10^6, Vicsek, per-step
    python -m bench.checkpoint_bench --n 100000 --steps 60 --sample-every 20

One JSON line. The same scenario runs twice through `execute_to_dir` (the CLI's path:
the state saved by the engine, written by service/checkpoints.py with fsync and rename,
into a real run folder): once without checkpoints and once checkpointing every
`--sample-every` steps, so that a few checkpoints land in a short run. A checkpoint's
cost C is the extra wall time over the checkpoints taken (`write_seconds` is the
part inside the writer, measured directly); a step's time T is the plain run's. The
figure asked for is the cost spread over `--every` (1000) steps: C / (every * T).
No frames are recorded and observables are taken every 1000 steps, as in a long run.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

from flocklab.schemas import Scenario


def scenario(n: int, steps: int, checkpoint_every: int) -> Scenario:
    return Scenario.model_validate({
        "model": {"kind": "vicsek", "rule": "vicsek", "v0": 0.03, "eta": 0.5},
        "space": {"kind": "periodic", "L": (n / 4) ** 0.5},
        "neighbours": {"radius": 1.0}, "initial": {"kind": "random", "N": n},
        "time": {"steps": steps, "dt": 1.0},
        "recording": {"observables_every": 1000, "checkpoint_every": checkpoint_every},
        "seed": 1, "backend": "cpu",
    })


def timed_run(sc: Scenario, folder: Path, writes: list[tuple[float, int]]) -> float:
    """Wall seconds of the stepping loop (setup excluded) of `sc` run into `folder`."""
    from flocklab.service import checkpoints, execute

    write = checkpoints.write_checkpoint

    def timed_write(where: Path, *args, **kw):
        t = time.perf_counter()
        write(where, *args, **kw)
        writes.append((time.perf_counter() - t, (where / checkpoints.CHECKPOINT).stat().st_size))

    execute.write_checkpoint = timed_write  # the module's own name: what _run_in calls
    try:
        t0 = time.perf_counter()
        out: dict = {}
        summary = execute.execute_to_dir(sc, folder, on_result=lambda r: out.update(
            setup=r.extra["setup_seconds"]))
        assert summary["status"] == "completed", summary
        return summary["wall_seconds"] - out["setup"] if out else time.perf_counter() - t0
    finally:
        execute.write_checkpoint = write


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=1_000_000)
    ap.add_argument("--steps", type=int, default=40)
    ap.add_argument("--sample-every", type=int, default=10,
                    help="checkpoint period of the measured run (steps)")
    ap.add_argument("--every", type=int, default=1000,
                    help="the checkpoint period the cost is spread over (steps)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(dir=".") as tmp:
        root = Path(tmp)
        timed_run(scenario(min(args.n, 20_000), 3, 1), root / "warm", [])  # compiles
        plain = timed_run(scenario(args.n, args.steps, 0), root / "plain", [])
        writes: list[tuple[float, int]] = []
        with_ckpt = timed_run(scenario(args.n, args.steps, args.sample_every),
                              root / "ckpt", writes)
    taken = len(writes)
    step = plain / args.steps
    written = sum(w for w, _ in writes)
    cost = max(with_ckpt - plain, written) / max(taken, 1)
    print(json.dumps({
        "bench": "checkpoint", "n_agents": args.n, "steps": args.steps,
        "checkpoints_taken": taken, "seconds_per_step": step,
        "checkpoint_seconds": cost, "write_seconds": written / max(taken, 1),
        "checkpoint_every": args.every,
        "cost_per_step_fraction": cost / (args.every * step),
        "checkpoint_bytes": writes[-1][1] if writes else 0,
    }))


if __name__ == "__main__":
    main()
