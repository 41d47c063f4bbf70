"""The version as pyproject.toml writes it (the one source), read from the file itself so
that tests compare what the installed code reports against it."""

from __future__ import annotations

import re
from pathlib import Path

PYPROJECT = Path(__file__).resolve().parents[1] / "pyproject.toml"


def pyproject_version() -> str:
    """`version` of the [project] table (a regex: tomllib is 3.11+)."""
    project = PYPROJECT.read_text().split("[project]", 1)[1].split("\n[", 1)[0]
    match = re.search(r'^version\s*=\s*"([^"]+)"\s*$', project, re.M)
    assert match, "pyproject.toml has no [project] version"
    return match.group(1)


VERSION = pyproject_version()
