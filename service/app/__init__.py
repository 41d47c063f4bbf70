"""The HTTP API: an app factory, routers per resource, settings, problem+json errors.

Never imports the engine: Taichi runs only in the worker processes of `service.jobs`.
"""

from .factory import create_app
from .settings import Settings, load_settings

__all__ = ["Settings", "create_app", "load_settings"]
