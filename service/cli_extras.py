"""The CLI's checks for the optional parts of an install, and `flocklab --version`.

`pip install flocklab` alone is the client (httpx, pydantic, numpy). The commands that
simulate (and `convert`, which writes GSD) need the `engine` extra and `serve` needs the
`service` extra; without them the command answers one line naming the extra and exits
with EXIT_MISSING_EXTRA, before anything imports the missing packages (so there is no
traceback to show).
"""

from __future__ import annotations

import importlib.metadata
import importlib.util

# Exit code of a command whose extra is not installed (documented in the module
# docstring of service/cli.py and in docs/CLI.md's exit codes).
EXIT_MISSING_EXTRA = 4

# The import names each extra brings, as the commands import them.
EXTRA_MODULES: dict[str, tuple[str, ...]] = {
    "engine": ("taichi", "h5py", "scipy", "gsd"),
    "service": ("fastapi", "uvicorn", "pydantic_settings", "h5py"),
}

# The extras each command needs (`render` checks its own `plot` extra when it draws).
COMMAND_EXTRAS: dict[str, tuple[str, ...]] = {
    "run": ("engine",),
    "sweep": ("engine",),
    "convert": ("engine",),  # h5py and gsd, the engine extra's file formats
    "serve": ("service",),
}


class MissingExtra(Exception):
    """An optional part of flocklab is not installed; the message says what to install."""


def missing_modules(extra: str) -> list[str]:
    """The import names of `extra` that cannot be found (found ones are not imported)."""
    return [m for m in EXTRA_MODULES[extra] if importlib.util.find_spec(m) is None]


def require_extras(command: str) -> None:
    """Raise MissingExtra when an extra that `command` needs is not installed."""
    for extra in COMMAND_EXTRAS.get(command, ()):
        absent = missing_modules(extra)
        if absent:
            raise MissingExtra(
                f"`flocklab {command}` needs the {extra} extra ({', '.join(absent)} not "
                f"installed): pip install 'flocklab[{extra}]' (from a checkout: "
                f"pip install -e '.[{extra}]')")


def version() -> str:
    """The installed distribution's version (flocklab.schemas.version)."""
    from flocklab.schemas.version import version as installed

    return installed()
