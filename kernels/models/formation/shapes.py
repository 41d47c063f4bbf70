"""F1's named formations: offsets b_i for any N, mean zero (paper condition 1), neighbours at
distance d (condition 2) and no two agents closer than d, so the repulsion vanishes once the
formation is reached.

Reference heading +x (`orientation` turns the whole shape counter-clockwise):
  column   one behind another along x
  line     abreast along y
  wedge    a filled triangle, apex at +x: rows of 1, 2, 3, ... agents of the triangular lattice
           (the last row partial, centred)
  diamond  a k x k square lattice, k = ceil(sqrt N), turned 45 deg with its apex at +x; for
           N < k^2 the points nearest the apex are kept
  circle   N agents on a circle of radius d / (2 sin(pi/N)), adjacent ones d apart
  hex      the N points of the triangular lattice nearest the origin (ties broken by angle)
"""

from __future__ import annotations

import math

import numpy as np

from flocklab.schemas.formation import ExplicitFormation, FormationSpec, NamedFormation

_SQ3 = math.sqrt(3.0)


def _column(n: int) -> np.ndarray:
    return np.stack([-np.arange(n, dtype=np.float64), np.zeros(n)], axis=1)


def _line(n: int) -> np.ndarray:
    return np.stack([np.zeros(n), np.arange(n, dtype=np.float64)], axis=1)


def _wedge(n: int) -> np.ndarray:
    # Agent m sits in row r (r(r+1)/2 <= m < (r+1)(r+2)/2) at slot j of r + 1.
    m = np.arange(n)
    r = np.floor((np.sqrt(8.0 * m + 1.0) - 1.0) / 2.0).astype(np.int64)
    r += (r + 1) * (r + 2) // 2 <= m  # guard the float floor
    r -= r * (r + 1) // 2 > m
    j = m - r * (r + 1) // 2
    last = r[-1]
    in_last = np.count_nonzero(r == last)
    # A partial last row takes the slots nearest its middle: shift by the free slots / 2.
    shift = np.where(r == last, (last + 1 - in_last) // 2, 0)
    y = (j + shift) - r / 2.0
    return np.stack([-r * (_SQ3 / 2.0), y], axis=1)


def _diamond(n: int) -> np.ndarray:
    k = math.isqrt(n - 1) + 1 if n > 1 else 1
    i, j = np.divmod(np.arange(k * k), k)
    order = np.lexsort((i, np.abs(i - j), i + j))[:n]  # from the apex backwards, centre first
    i, j = i[order].astype(np.float64), j[order].astype(np.float64)
    c = math.sqrt(0.5)
    return np.stack([-(i + j) * c, (i - j) * c], axis=1)


def _circle(n: int) -> np.ndarray:
    if n == 1:
        return np.zeros((1, 2))
    rad = 0.5 / math.sin(math.pi / n)
    ang = 2.0 * np.pi * np.arange(n) / n
    return rad * np.stack([np.cos(ang), np.sin(ang)], axis=1)


def _hex(n: int) -> np.ndarray:
    # Lattice a (1, 0) + b (1/2, sqrt3/2); a disc of radius R holds ~ 2 pi R^2 / sqrt3 points.
    reach = math.isqrt(int(n * _SQ3 / (2.0 * math.pi)) + 1) + 3
    a, b = np.meshgrid(np.arange(-2 * reach, 2 * reach + 1), np.arange(-reach, reach + 1))
    x = a.ravel() + 0.5 * b.ravel()
    y = (_SQ3 / 2.0) * b.ravel()
    r2 = np.round(x * x + y * y, 9)
    ang = np.round(np.mod(np.arctan2(y, x), 2.0 * np.pi), 12)
    order = np.lexsort((ang, r2))[:n]
    return np.stack([x[order], y[order]], axis=1)


_SHAPES = {
    "column": _column, "line": _line, "wedge": _wedge, "diamond": _diamond,
    "circle": _circle, "hex": _hex,
}


def named_offsets(shape: str, n: int, d: float, orientation: float = 0.0) -> np.ndarray:
    """(n, 2) offsets of a named formation with neighbour spacing d, mean zero."""
    b = _SHAPES[shape](n) * d
    b -= b.mean(axis=0)
    if orientation:
        b = b @ rotation(orientation).T
    return b


def offsets(spec: FormationSpec, n: int, d: float) -> np.ndarray:
    """The offsets a formation spec stands for, (n, 2) in agent-id order."""
    if isinstance(spec, NamedFormation):
        return named_offsets(spec.shape, n, d, spec.orientation)
    assert isinstance(spec, ExplicitFormation)
    return np.asarray(spec.offsets, dtype=np.float64).reshape(n, 2)


def rotation(angle: float) -> np.ndarray:
    """The 2x2 counter-clockwise rotation by `angle` radians."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s], [s, c]])
