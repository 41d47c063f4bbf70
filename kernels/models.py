"""Every model family's kernel: one registration line per family."""

from . import vicsek  # noqa: F401
from .flocking import FlockingKernel  # noqa: F401
from .formation import FormationKernel  # noqa: F401
from .model import KERNELS
from .obstacles import ObstacleFlockingKernel  # noqa: F401

__all__ = ["KERNELS"]
