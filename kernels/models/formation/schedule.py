"""F1's offsets over time: b_i(t) = sum over at most two stored formations K of M_K(t) K[i].

K_0 is the initial formation; change c turns the formation in force, B_c, into B_{c+1} over
[start_c, end_c]:
  rotate phi   b(t) = R(s phi) B_c                  (B_{c+1} = R(phi) B_c)
  morph to K'  b(t) = (1 - s) B_c + s K'            (B_{c+1} = K')
with s = s(u), u = (t - start)/(end - start), smoothstep 3u^2 - 2u^3 or linear; outside
every change b = the last completed B. Only the initial formation and the morph targets are
stored: every B_c is R B for a stored B and a rotation R. Every stored formation has mean
zero, so b(t) keeps mean zero (paper condition 1); a rotation keeps every pair distance
(condition 2).
"""

from __future__ import annotations

import numpy as np

from flocklab.schemas.formation import FormationChange, FormationSpec

from .shapes import offsets, rotation

_I = np.eye(2)


class OffsetSchedule:
    def __init__(self, first: FormationSpec, changes: list[FormationChange], n: int, d: float):
        self.changes = changes
        self.stored = [offsets(first, n, d)]
        # B_c = in_force[c][1] @ stored[in_force[c][0]] (as 2x2 acting on each offset)
        self.in_force: list[tuple[int, np.ndarray]] = [(0, _I)]
        for c in changes:
            k, m = self.in_force[-1]
            if c.rotate is not None:
                self.in_force.append((k, rotation(c.rotate) @ m))
            else:
                self.stored.append(offsets(c.formation, n, d))
                self.in_force.append((len(self.stored) - 1, _I))

    def weights(self, t: float) -> dict[int, np.ndarray]:
        """{stored formation index: 2x2 matrix M} with b_i(t) = sum M stored[k][i]."""
        done = 0
        for j, c in enumerate(self.changes):
            if t < c.start:
                break
            if t >= c.end:
                done = j + 1
                continue
            u = (t - c.start) / (c.end - c.start)
            s = u * u * (3.0 - 2.0 * u) if c.relaxation == "smoothstep" else u
            k, m = self.in_force[j]
            if c.rotate is not None:
                return {k: rotation(s * c.rotate) @ m}
            target = self.in_force[j + 1][0]
            return {k: (1.0 - s) * m, target: s * _I}
        k, m = self.in_force[done]
        return {k: m}

    def at(self, t: float) -> np.ndarray:
        """b_i(t), (N, 2) in agent-id order."""
        b = np.zeros_like(self.stored[0])
        for k, m in self.weights(t).items():
            x, y = self.stored[k][:, 0], self.stored[k][:, 1]
            b[:, 0] += m[0, 0] * x + m[0, 1] * y
            b[:, 1] += m[1, 0] * x + m[1, 1] * y
        return b
