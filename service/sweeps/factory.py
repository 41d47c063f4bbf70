"""The executor a configuration names: local worker processes, or a Ray cluster.

Apart from executors.py (the base every executor builds on, which ray_executor.py
imports), so that choosing Ray, which imports the base, closes no import circle.
"""

from __future__ import annotations

from typing import Any

from .executors import Executor, ExecutorConfig, LocalExecutor


def make_executor(config: ExecutorConfig | dict[str, Any] | None) -> Executor:
    """The executor `config` names (local when None)."""
    if config is None:
        return LocalExecutor()
    if isinstance(config, dict):
        config = ExecutorConfig(**config)
    if config.kind == "local":
        return LocalExecutor()
    from .ray_executor import RayExecutor

    return RayExecutor(config)
