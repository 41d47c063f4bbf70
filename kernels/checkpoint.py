"""What a checkpoint of a running set of replicas holds, as the engine sees it.

A checkpoint is taken by the driver (kernels/driver.py) at the end of a window, which
never changes a bit: every schedule's `save()` gives the whole state the next step reads
as named numpy arrays (agent state in its storage order with the ids that undo it, the
per-replica counters, the observable accumulators such as Theorem 2's linked-interval
tracking and the observation rows so far), and `load()` puts them back into a schedule
freshly built from the same scenario. The noise is counter-based (kernels/space/rng.py):
there is no generator state to keep. The files and their fingerprint are the service's
(service/checkpoints.py); the engine knows nothing of files.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

import numpy as np

# Bumped whenever a change of the engine changes any bit of any run: a checkpoint taken
# under another value is refused, since its continuation would not be the run it began.
ENGINE_BITS = "2025.1"
STEP = "driver/step"  # the key of the step a checkpoint was taken at
PATH, BACKEND = "driver/path", "driver/backend"  # the schedule and backend that ran

State = Mapping[str, np.ndarray]
# (step, state): called by the driver at each checkpoint; the state holds STEP.
CheckpointFn = Callable[[int, dict[str, np.ndarray]], None]


class CheckpointUnsupported(ValueError):
    """The schedule cannot save its whole state exactly (the message says what is
    missing): the run is refused a checkpoint rather than resumed inexactly."""


class CheckpointMismatch(ValueError):
    """A checkpoint's arrays do not fit the schedule built from the scenario."""


def put(held, name: str, value: np.ndarray) -> None:
    """Copy `value` into the array `held` (numpy, in place: a fused kernel runs on that
    memory; or a `ti.Ndarray`), refusing another shape or dtype."""
    shape = tuple(held.shape) if isinstance(held, np.ndarray) else tuple(
        held.to_numpy().shape)
    dtype = held.dtype if isinstance(held, np.ndarray) else held.to_numpy().dtype
    if tuple(value.shape) != shape or value.dtype != dtype:
        raise CheckpointMismatch(f"{name}: {value.dtype}{list(value.shape)} where the "
                                 f"schedule holds {dtype}{list(shape)}")
    if isinstance(held, np.ndarray):
        held[...] = value
    else:
        held.from_numpy(value)
