"""F1's offsets over time: b_i(t) = sum over at most two stored formations K of M_K(t) K[i].

K_0 is the initial formation; change c turns the formation in force, B_c, into B_{c+1} over
[start_c, end_c]:
  rotate phi   b(t) = R(s phi) B_c                  (B_{c+1} = R(phi) B_c)
  morph to K'  b(t) = (1 - s) B_c + s K'            (B_{c+1} = K')
with s = s(u), u = (t - start)/(end - start), smoothstep 3u^2 - 2u^3 or linear; outside
every change b = the last completed B. Only the initial formation and the morph targets are
stored: every B_c is R B for a stored B and a rotation R. Every stored formation has mean
zero, so b(t) keeps mean zero (paper condition 1); a rotation keeps every pair distance
(condition 2). In 3D the matrices are 3x3 and R(phi) turns about the change's axis
(default z).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from flocklab.schemas.formation import FormationChange, FormationSpec

from .shapes import offsets, rotation, rotation3

_Z_AXIS = (0.0, 0.0, 1.0)


class OffsetSchedule:
    def __init__(self, first: FormationSpec, changes: list[FormationChange], n: int, d: float,
                 dim: int = 2):
        self.changes = changes
        self.n, self.dim = n, dim
        self._rows: dict[int, Callable[[np.ndarray], np.ndarray]] = {}  # released formations
        self._eye = np.eye(dim)
        self.stored = [offsets(first, n, d, dim)]
        # B_c = in_force[c][1] @ stored[in_force[c][0]] (as dim x dim acting on each offset)
        self.in_force: list[tuple[int, np.ndarray]] = [(0, self._eye)]
        for c in changes:
            k, m = self.in_force[-1]
            if c.rotate is not None:
                self.in_force.append((k, self._rotation(c, c.rotate) @ m))
            else:
                self.stored.append(offsets(c.formation, n, d, dim))
                self.in_force.append((len(self.stored) - 1, self._eye))

    def _rotation(self, change: FormationChange, angle: float) -> np.ndarray:
        """The change's rotation by `angle`: in the plane, or about its axis in 3D."""
        if self.dim == 2:
            return rotation(angle)
        return rotation3(angle, change.axis or _Z_AXIS)

    def weights(self, t: float) -> dict[int, np.ndarray]:
        """{stored formation index: dim x dim matrix M} with b_i(t) = sum M stored[k][i]."""
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
                return {k: self._rotation(c, s * c.rotate) @ m}
            target = self.in_force[j + 1][0]
            return {k: (1.0 - s) * m, target: s * self._eye}
        k, m = self.in_force[done]
        return {k: m}

    def release(self, k: int, rows: Callable[[np.ndarray], np.ndarray]) -> None:
        """Drop stored formation k's host offsets: `rows(ids)` gives those of agents `ids`
        back, bit for bit (from the device's float64 copy)."""
        self.stored[k] = None
        self._rows[k] = rows

    def at(self, t: float, ids: np.ndarray | None = None) -> np.ndarray:
        """b_i(t), (N, dim) in agent-id order; with `ids`, the rows of those agents (the
        only way to read a released formation)."""
        b = np.zeros((self.n if ids is None else len(ids), self.dim))
        for k, m in self.weights(t).items():
            src = self._rows[k](ids) if k in self._rows else (
                self.stored[k] if ids is None else self.stored[k][ids])
            cols = [src[:, c] for c in range(self.dim)]
            for r in range(self.dim):
                # the terms summed left to right, as the 2D-only code wrote them out
                row = m[r, 0] * cols[0]
                for c in range(1, self.dim):
                    row = row + m[r, c] * cols[c]
                b[:, r] += row
        return b
