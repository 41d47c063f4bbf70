"""Counter-based random numbers: u = hash(seed, stream, step, agent id).

Noise must not depend on thread scheduling or on the order agents are stored in, so no
generator state is shared: every draw is a pure function of its coordinates. The hash is
the `lowbias32` integer finaliser (Chris Wellons), applied in a chain. The numpy twin
produces the same bits, so a brute-force reference can replay a noisy run exactly.

The hash is 32 bits in both precisions. float64 holds all 32 as u = h 2^-32; float32 keeps
the top 24 (u = (h >> 8) 2^-24), since h 2^-32 rounded to float32 could reach 1.0.
"""

import numpy as np
import taichi as ti

from .. import runtime

_M32 = 0xFFFFFFFF
_C1 = 0x7FEB352D
_C2 = 0x846CA68B


def _mix_int(x: int) -> int:
    x &= _M32
    x ^= x >> 16
    x = (x * _C1) & _M32
    x ^= x >> 15
    x = (x * _C2) & _M32
    x ^= x >> 16
    return x


def step_key(seed: int, stream: int, step: int) -> int:
    """A 32-bit key for one (seed, stream, step); kernels combine it with the agent id."""
    return _mix_int(seed_key(seed, stream) ^ _mix_int(step & _M32) ^ ((step >> 32) & _M32))


@ti.func
def _mix(x):
    x ^= x >> ti.u32(16)
    x *= ti.u32(_C1)
    x ^= x >> ti.u32(15)
    x *= ti.u32(_C2)
    x ^= x >> ti.u32(16)
    return x


@ti.func
def uniform(key, agent):
    """Uniform in [0, 1) with 32 random bits (24 in float32), from a step key and an
    agent id."""
    h = _mix(_mix(ti.cast(agent, ti.u32) ^ key) + ti.u32(0x9E3779B9))
    u = 0.0
    if ti.static(runtime.current().precision == "float32"):
        u = ti.cast(h >> ti.u32(8), float) * (1.0 / 16777216.0)
    else:
        u = ti.cast(h, float) * (1.0 / 4294967296.0)
    return u


def _mix_np(x: np.ndarray) -> np.ndarray:
    x = x.astype(np.uint32)
    x ^= x >> np.uint32(16)
    x *= np.uint32(_C1)
    x ^= x >> np.uint32(15)
    x *= np.uint32(_C2)
    x ^= x >> np.uint32(16)
    return x


def uniform_np(key: int, agents: np.ndarray, precision: str = "float64") -> np.ndarray:
    """numpy twin of `uniform` (same bits, in `precision`'s type)."""
    h = _mix_np(_mix_np(agents.astype(np.uint32) ^ np.uint32(key)) + np.uint32(0x9E3779B9))
    if precision == "float32":
        return (h >> np.uint32(8)).astype(np.float32) * np.float32(1.0 / 16777216.0)
    return h.astype(np.float64) * (1.0 / 4294967296.0)


def seed_key(seed: int, stream: int) -> int:
    """The (seed, stream) part of `step_key`: step_key = mix(seed_key ^ mix(step)) for
    steps below 2^32, which a kernel can finish itself."""
    k = _mix_int(_mix_int((seed >> 32) & _M32) ^ (seed & _M32))
    return _mix_int(k ^ _mix_int(stream))
