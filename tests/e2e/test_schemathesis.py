"""Property-based requests over the whole OpenAPI document: no 5xx, ever (bounded run)."""

from __future__ import annotations

import re
import subprocess
import sys

import pytest

from tests.service.conftest import TEST_ENV

pytest.importorskip("schemathesis")


def test_no_server_errors_anywhere(make_server, tmp_path):
    # Tiny limits so that generated scenarios which are valid run in milliseconds.
    s = make_server({**TEST_ENV, "FLOCKLAB_MAX_AGENTS": "200", "FLOCKLAB_MAX_STEPS": "50",
                     "FLOCKLAB_MAX_QUEUED": "8"})
    cmd = [sys.executable, "-m", "schemathesis.cli", "run", f"{s.url}/openapi.json",
           "--checks", "not_a_server_error",
           "--max-examples", "15", "--seed", "1", "--workers", "1", "--no-color",
           "--request-timeout", "30", "--phases", "examples,coverage,fuzzing",
           "--generation-database", "none", "--suppress-health-check", "all",
           "--report-dir", str(tmp_path / "report")]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=300, cwd=tmp_path)
    out = r.stdout + r.stderr
    assert r.returncode == 0, out[-6000:]
    passed = re.search(r"(\d+) generated, (\d+) passed", out)
    assert passed and int(passed.group(2)) >= 100, out[-3000:]
