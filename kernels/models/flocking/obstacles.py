"""M3 kernel: Tanner's flocking among obstacles towards a destination (paper 002).

M2's metric flock (kernel.py) with two parts of its own:
  radius.AgentRadii  N_i = {j : |r_ij| <= R_i}, U_ij saturated at R_i (or min(R_i, R_j)),
                     R_i adapted by eq. 4 after sorting, before the step's motion;
  mission.Mission    - grad_{r_i} V_i - c_d v_i [region] in u_i (eq. 3), V_i the navigation
                     function over the obstacle grid (navigation.py); sum_i V_i in Q (eq. 5).
So per step: the adaptive radius (at its cadence), then
  u_i = - sum_{j in N_i} [(v_i - v_j) + grad_{r_i} U_ij] - grad_{r_i} V_i - c_d v_i [region],
then the integrator (as M2).
"""

from flocklab.schemas import Scenario

from ...model import register_kernel
from ...runtime import DevicePolicy
from .kernel import Flock
from .mission import Mission
from .radius import AgentRadii


@register_kernel
class ObstacleFlockingKernel(Flock):
    kind = "flocking_obstacles"

    def __init__(self, scenario: Scenario, policy: DevicePolicy):
        p = scenario.model
        super().__init__(scenario, policy, False, AgentRadii(p, scenario.neighbours.radius),
                         Mission(p, scenario.dimension, policy))
