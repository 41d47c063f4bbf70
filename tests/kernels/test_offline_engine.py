"""The engine stays on this machine: ti.init's daily version check (a thread posting a
client id to Taichi's web server) must not start in a flocklab process."""

import subprocess
import sys

import pytest

PROBE = r"""
import threading
started = []
_start = threading.Thread.start
def start(self):
    started.append(self.name)
    _start(self)
threading.Thread.start = start
from flocklab import kernels
from flocklab.schemas import Scenario
res = kernels.run(Scenario.model_validate({
    "model": {"kind": "vicsek", "v0": 0.03, "eta": 0.5},
    "space": {"kind": "periodic", "L": 3.0}, "neighbours": {"radius": 1.0},
    "initial": {"kind": "random", "N": 10},
    "time": {"steps": 3}, "seed": 1}))
assert res.status == "completed", res.status
print("THREADS", started)
"""


@pytest.mark.slow
def test_no_version_check_thread():
    out = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr
    line = next(ln for ln in out.stdout.splitlines() if ln.startswith("THREADS"))
    assert "try_check_version" not in line, line


@pytest.mark.slow
def test_version_check_is_what_the_probe_sees():
    """The probe would see the thread if the setting were off (so the test above can fail)."""
    probe = PROBE.replace("from flocklab import kernels",
                          "import os; os.environ['TI_SKIP_VERSION_CHECK'] = 'OFF'\n"
                          "from flocklab import kernels")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr
    assert "try_check_version" in out.stdout
