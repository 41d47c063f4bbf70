"""The full kernel registry, every family imported (for tooling and tests); the engine
imports only the family a scenario needs, through `kernels.model.kernel_for`."""

import importlib

from .model import KERNELS, MODULES

for _module in MODULES.values():
    importlib.import_module(_module)

__all__ = ["KERNELS"]
