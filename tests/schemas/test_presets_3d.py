"""The 3D flocking preset behaves as paper 000's theorem says on the engine's discrete
steps: Q (eq. 10) does not increase, no pair collides, speeds stay bounded. (With R = 2
instead of the preset's 1.5, Q rose from t = 3 s and speeds reached 10^3: a stiff
configuration that the Euler step could not resolve, and a preset that showed it.)"""

import numpy as np
import pytest

from flocklab import kernels
from flocklab.schemas import Scenario, get_preset


@pytest.mark.slow
def test_tjp_switching_3d_keeps_q_non_increasing(taichi_cpu):
    spec = get_preset("tjp-switching-3d").model_dump(mode="json")
    spec["time"]["steps"] = 800  # 8 s: past where R = 2 first let Q rise (t = 3 s)
    spec["recording"] = {"every": 0, "observables_every": 20}
    res = kernels.run(Scenario.model_validate(spec))
    assert res.status == "completed"
    obs = res.observables
    q = np.asarray(obs["Q"])
    assert len(q) == 41
    assert np.all(np.diff(q) <= 1e-9 * abs(q[0])), np.diff(q).max()
    assert q[-1] < q[0]
    # Q bounds the kinetic energy; the R = 2 run reached speeds of 65 by t = 3 s
    assert np.max(obs["speed_max"]) < 2 * obs["speed_max"][0]
    assert np.min(obs["min_distance"]) > 0.3
