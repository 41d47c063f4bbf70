"""A pytest plugin that runs the suite's model tests in float32 (docs/PRECISION.md):

    python -m pytest -p tests.float32_plugin tests/kernels/vicsek/test_vicsek.py \
        tests/kernels/formation/test_formation.py

Every Scenario defaults to precision float32, and so does every direct runtime.ensure
(the tests that build kernels themselves). The float64 tolerances then fail where float32
cannot reach them: the point is to see which checks hold and by how much the rest miss.
Not collected by default (not a test_ module); never import it from a test.
"""

from flocklab.kernels import runtime
from flocklab.schemas import Scenario

runtime.ensure.__defaults__ = (None, "float32")
Scenario.model_fields["precision"].default = "float32"
Scenario.model_rebuild(force=True)
