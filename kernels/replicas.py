"""The one model interface the driver runs: a set of replicas advanced window by window.

Every schedule presents its model as `Replicas`: the per-step schedule (kernels/per_step.py:
one replica, one launch per pass, parallel over its agents), the fused one (many replicas,
many steps per launch, one replica per CPU task) and the batched one (every replica's agents
in one launch per step). kernels/driver.py runs any of them through the same loop.

Also here: what the fused batches share (`FusedBatch`: host copies of device arrays, the
per-replica integer slots; `Snapshots`: a buffer for host-side observables; `host_array`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, Protocol

import numpy as np

from flocklab.schemas import Scenario

from .checkpoint import CheckpointUnsupported, put


class Replicas(Protocol):
    """What a schedule offers the driver. `advance(s0, s1)` takes every replica from step s0
    towards s1: at each step s it observes first when s is an observation step
    (`observables_every`, and each replica's last step), then steps unless s is the last;
    a replica that diverged or reached its end stays put. `status()` is a snapshot of the
    per-replica counters that the per-replica readers take. `frame(b, arrays, step)` is replica
b's state arrays at `step` (its current one) in agent-id order, with the derived arrays its
recording names (`recording.derived`) where the schedule computes them."""

    scenarios: list[Scenario]
    QUEUED: bool  # replicas go to threads from a queue (the driver orders them largest first)

    def advance(self, s0: int, s1: int) -> None: ...
    def end_at(self, step: int) -> None: ...
    def status(self) -> np.ndarray: ...
    def observables(self, b: int, status: np.ndarray) -> dict[str, np.ndarray]: ...
    def frame(self, b: int, arrays: list[str], step: int) -> dict[str, np.ndarray]: ...
    def convergence_keys(self) -> list[str]: ...
    def extra(self, b: int, status: np.ndarray) -> dict[str, Any]: ...
    def divergence(self, b: int, status: np.ndarray) -> tuple[int, str, str] | None: ...
    # Checkpoints (kernels/checkpoint.py): the whole state the next step reads, and back
    # into a set freshly built from the same scenarios. save raises CheckpointUnsupported
    # where the schedule cannot save it exactly.
    def save(self) -> dict[str, np.ndarray]: ...
    def load(self, state: Mapping[str, np.ndarray]) -> None: ...


def host_array(a: np.ndarray, dtype: Any) -> np.ndarray:
    """`a` as a C-contiguous numpy array of `dtype` starting on a 64-byte line, for a fused
    kernel to run on in place (see FusedBatch). numpy aligns only to 16 bytes: rows of
    four doubles then straddle cache lines, which made the Vicsek kernel 10% slower."""
    dtype = np.dtype(dtype)
    nbytes = a.size * dtype.itemsize
    buf = np.empty(nbytes + 64, np.uint8)
    off = -buf.ctypes.data % 64
    out = buf[off:off + nbytes].view(dtype).reshape(a.shape)
    out[...] = a
    return out


class Snapshots:
    """A fused batch's snapshot buffer, for an observable the host computes (the flocking
    path's lambda_2, 3D F2's D3): at each observation the kernel writes `width` values per
    agent of each replica that takes them into its K rows (rows SNAP0 .. NOBS of the launch,
    from `base[b]`), and the host reads them after the launch. A window is cut into launches
    of at most `chunk` steps, so that K rows hold every observation of one, which never
    changes a bit; chunk is None when no replica takes snapshots (one launch a window)."""

    def __init__(self, ns: Sequence[int], rows: Sequence[int], on: Sequence[bool],
                 everies: Sequence[int], width: int, doubles: int):
        agents = sum(n for n, o in zip(ns, on, strict=True) if o)
        self.K = max(3, min(max(rows), doubles // max(width * agents, 1)))
        # a launch of chunk steps observes at most chunk / every + 2 rows (the last step)
        taking = [e for e, o in zip(everies, on, strict=True) if o]
        self.chunk = max(1, (self.K - 2) * min(taking)) if taking else None
        sizes = [self.K * width * n if o else 0 for n, o in zip(ns, on, strict=True)]
        self.base = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int32)
        self.ns, self.on, self.width = list(ns), list(on), width

    def launches(self, s0: int, s1: int) -> list[tuple[int, int]]:
        """The launches (a, b) of the window s0 .. s1."""
        step = s1 - s0 if self.chunk is None else self.chunk
        return [(a, min(a + step, s1)) for a in range(s0, s1, step)]

    def taken(self, snap: np.ndarray, first: np.ndarray, last: np.ndarray):
        """(b, r0, r1, values (r1 - r0, n, width)) for each replica that took rows r0 .. r1
        in the last launch (first, last: each replica's SNAP0 and NOBS slots)."""
        for b, on in enumerate(self.on):
            r0, r1 = int(first[b]), int(last[b])
            if on and r1 > r0:
                n = self.ns[b]
                vals = snap[self.base[b]:self.base[b] + (r1 - r0) * n * self.width]
                yield b, r0, r1, vals.reshape(r1 - r0, n, self.width)


class FusedBatch:
    """What every model's fused batch shares: its device arrays `args`, among them `iprm`,
    the per-replica integer slots whose slot 0 is the replica's last step; and host copies
    of the arrays, fetched once per window and shared by every replica's reader (copying a
    whole array per replica made reading a batch's results O(B^2): at 64 replicas, most of
    a sweep's system time).

    An array of `args` may be a numpy array (`host_array`) rather than a `ti.Ndarray`: the
    CPU backend runs the kernel on its memory in place, which spares the from/to-numpy
    kernels (each one's Python AST re-read and its code loaded at every process start) and
    a launch per read. Readers still get copies: a frame or a series handed out must not
    change under its holder when the next window runs."""

    args: dict[str, Any]
    STEPS = 0  # iprm slot of each replica's last step
    # Whether the kernel's threads take replicas from a queue, each the next one left (then
    # the driver hands them over largest first); else each CPU task runs one replica, and
    # the tasks go to the threads in contiguous blocks, so the driver keeps the input order
    # (largest first would give one thread all the large replicas).
    QUEUED = False
    dimensions: tuple[int, ...] = (2,)  # the values of space.dimension the kernel runs

    def end_at(self, step: int) -> None:
        """Make `step` every replica's last (cancellation): the next window observes it."""
        self.invalidate()
        held = self.args["iprm"]
        iprm = _copy(held)
        iprm[:, self.STEPS] = np.minimum(iprm[:, self.STEPS], step)
        if isinstance(held, np.ndarray):
            held[...] = iprm
        else:
            held.from_numpy(iprm)

    def status(self) -> np.ndarray:
        """Per-replica integer slots (steps, observation count, divergence step, ...)."""
        return _copy(self.args["iprm"])

    def host(self, name: str) -> np.ndarray:
        cache = self.__dict__.setdefault("_host_copies", {})
        if name not in cache:
            cache[name] = _copy(self.args[name])
        return cache[name]

    def invalidate(self) -> None:
        """Forget the copies: the device arrays are about to change."""
        self.__dict__.get("_host_copies", {}).clear()

    # Whether every bit the next window reads is in `args` and `save_host` (a model's
    # batch says so once its host-side state is saved too).
    CHECKPOINTS = False

    def save(self) -> dict[str, np.ndarray]:
        """Every array of `args` (the state, the counters and slots, the observation rows
        and the scratch, which the next window overwrites: saving it too costs little at
        the fused schedule's N and keeps the rule simple), and `save_host`'s arrays."""
        if not self.CHECKPOINTS:
            raise CheckpointUnsupported(f"the {type(self).__name__} schedule saves no "
                                        "checkpoints (take path per_step)")
        return {**{f"args/{k}": _copy(v) for k, v in self.args.items()}, **self.save_host()}

    def load(self, state: Mapping[str, np.ndarray]) -> None:
        """Back into this batch, built from the same scenarios as the saved one."""
        self.invalidate()
        for k, held in self.args.items():
            put(held, f"args/{k}", state[f"args/{k}"])
        self.load_host(state)

    def save_host(self) -> dict[str, np.ndarray]:
        """What a batch keeps on the host across windows (none here)."""
        return {}

    def load_host(self, state: Mapping[str, np.ndarray]) -> None:
        """Back from `save_host`'s arrays."""


def _copy(a: Any) -> np.ndarray:
    """A host copy of a batch's array (a numpy array or a `ti.Ndarray`)."""
    return a.copy() if isinstance(a, np.ndarray) else a.to_numpy()
