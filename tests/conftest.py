import os

import pytest

os.environ.setdefault("TI_LOG_LEVEL", "warn")


@pytest.fixture(scope="session")
def taichi_cpu():
    """Taichi on the CPU in the test process (all engine tests run on the main thread)."""
    from kernels import runtime

    return runtime.ensure("cpu")
