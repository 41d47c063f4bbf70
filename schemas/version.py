"""flocklab's version, written once: `version` in pyproject.toml, read here from the
installed distribution's metadata (importlib.metadata). The service (OpenAPI document,
H5MD `creator`, `summary.json`, `sweep.json`), the client (its User-Agent) and
`flocklab --version` all take it from here, so no module can disagree with the package."""

from __future__ import annotations

from functools import cache
from importlib import metadata

DISTRIBUTION = "flocklab"
UNKNOWN = "0+unknown"  # a source tree on sys.path that was never installed


@cache
def version() -> str:
    """The installed distribution's version (read once: importlib.metadata scans
    sys.path, tens of milliseconds)."""
    try:
        return metadata.version(DISTRIBUTION)
    except metadata.PackageNotFoundError:
        return UNKNOWN
