"""Counter-based random numbers: u = hash(seed, stream, step, agent id).

Noise must not depend on thread scheduling or on the order agents are stored in, so no
generator state is shared: every draw is a pure function of its coordinates. The hash is
the `lowbias32` integer finaliser (Chris Wellons), applied in a chain. The numpy twin
produces the same bits, so a brute-force reference can replay a noisy run exactly.
"""

import numpy as np
import taichi as ti

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
    """Uniform in [0, 1) with 32 random bits, from a step key and an agent id."""
    h = _mix(_mix(ti.cast(agent, ti.u32) ^ key) + ti.u32(0x9E3779B9))
    return ti.cast(h, ti.f64) * (1.0 / 4294967296.0)


def _mix_np(x: np.ndarray) -> np.ndarray:
    x = x.astype(np.uint32)
    x ^= x >> np.uint32(16)
    x *= np.uint32(_C1)
    x ^= x >> np.uint32(15)
    x *= np.uint32(_C2)
    x ^= x >> np.uint32(16)
    return x


def uniform_np(key: int, agents: np.ndarray) -> np.ndarray:
    """numpy twin of `uniform` (same bits)."""
    h = _mix_np(_mix_np(agents.astype(np.uint32) ^ np.uint32(key)) + np.uint32(0x9E3779B9))
    return h.astype(np.float64) * (1.0 / 4294967296.0)


def seed_key(seed: int, stream: int) -> int:
    """The (seed, stream) part of `step_key`: step_key = mix(seed_key ^ mix(step)) for
    steps below 2^32, which a kernel can finish itself."""
    k = _mix_int(_mix_int((seed >> 32) & _M32) ^ (seed & _M32))
    return _mix_int(k ^ _mix_int(stream))
