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
3D only:
  cube     a cubic lattice of spacing d, m = ceil(N^(1/3)) a side, filled x fastest, then y,
           then z (N = m^3: the full cube; else the top layer partial)
  shell    a Fibonacci sphere: z_k = 1 - (2k + 1)/N, azimuth k times the golden angle
           (points spread evenly in area), centred, its radius set so that the nearest pair
           is exactly d apart (so no two agents closer than d; not every agent has a
           neighbour at exactly d, as no N-point sphere packing is regular in general)
In 3D the plane shapes lie in the xy plane (z = 0), and `orientation` turns about z.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree

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
    # The n points of the grid |a| <= 2 reach, |b| <= reach nearest the origin, ties broken
    # by angle. Only the grid points inside a radius rho whose disc holds the n nearest
    # are ranked (~n of them, against the grid's ~2.2 n: 160 B/agent of temporaries at
    # 10^6), in the grid's own order, so the stable sort picks the same n in the same order.
    reach = math.isqrt(int(n * _SQ3 / (2.0 * math.pi)) + 1) + 3
    rho2 = (math.sqrt(n * _SQ3 / (2.0 * math.pi)) + 2.0) ** 2
    while True:
        x, y = _hex_within(reach, rho2)
        r2 = np.round(x * x + y * y, 9)
        if (len(r2) >= n and np.partition(r2, n - 1)[n - 1] < rho2 - 1e-6) or (
                len(r2) == (4 * reach + 1) * (2 * reach + 1)):
            break  # every point left out lies farther than the n-th nearest
        rho2 *= 2.0
    ang = np.round(np.mod(np.arctan2(y, x), 2.0 * np.pi), 12)
    order = np.lexsort((ang, r2))[:n]
    return np.stack([x[order], y[order]], axis=1)


def _hex_within(reach: int, rho2: float) -> tuple[np.ndarray, np.ndarray]:
    """x and y of the grid points a + b/2, (sqrt3/2) b, |a| <= 2 reach, |b| <= reach,
    with x^2 + y^2 <= rho2, row by row (b, then a, ascending: the grid's order)."""
    xs, ys = [], []
    for b in range(-reach, reach + 1):
        yb = (_SQ3 / 2.0) * b
        if yb * yb > rho2:
            continue
        half = math.sqrt(rho2 - yb * yb) + 1.0
        a = np.arange(max(-2 * reach, math.floor(-half - 0.5 * b)),
                      min(2 * reach, math.ceil(half - 0.5 * b)) + 1)
        x = a + 0.5 * b
        keep = x * x + yb * yb <= rho2
        xs.append(x[keep])
        ys.append(np.full(np.count_nonzero(keep), yb))
    return np.concatenate(xs), np.concatenate(ys)


def _cube(n: int) -> np.ndarray:
    m = max(1, round(n ** (1.0 / 3.0)))
    while m**3 < n:
        m += 1
    k = np.arange(n)
    b = np.empty((n, 3))
    b[:, 0], b[:, 1], b[:, 2] = k % m, (k // m) % m, k // (m * m)
    return b


def _shell(n: int) -> np.ndarray:
    if n == 1:
        return np.zeros((1, 3))
    k = np.arange(n, dtype=np.float64)
    z = 1.0 - (2.0 * k + 1.0) / n
    rho = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    phi = k * (math.pi * (3.0 - math.sqrt(5.0)))  # the golden angle
    b = np.stack([rho * np.cos(phi), rho * np.sin(phi), z], axis=1)
    b -= b.mean(axis=0)
    nearest, _ = cKDTree(b).query(b, k=2)
    return b / nearest[:, 1].min()  # the nearest pair at distance 1


_SHAPES = {
    "column": _column, "line": _line, "wedge": _wedge, "diamond": _diamond,
    "circle": _circle, "hex": _hex,
}
_SHAPES_3D = {"cube": _cube, "shell": _shell}


def named_offsets(shape: str, n: int, d: float, orientation: float = 0.0,
                  dim: int = 2) -> np.ndarray:
    """(n, dim) offsets of a named formation with neighbour spacing d, mean zero."""
    if shape in _SHAPES_3D:
        b = _SHAPES_3D[shape](n)
        b *= d
        b -= b.mean(axis=0)
        return b @ rotation3(orientation, (0.0, 0.0, 1.0)).T if orientation else b
    b = _SHAPES[shape](n)
    b *= d
    b -= b.mean(axis=0)
    if orientation:
        b = b @ rotation(orientation).T
    return b if dim == 2 else np.concatenate([b, np.zeros((n, 1))], axis=1)


def offsets(spec: FormationSpec, n: int, d: float, dim: int = 2) -> np.ndarray:
    """The offsets a formation spec stands for, (n, dim) in agent-id order."""
    if isinstance(spec, NamedFormation):
        return named_offsets(spec.shape, n, d, spec.orientation, dim)
    assert isinstance(spec, ExplicitFormation)
    return np.asarray(spec.offsets, dtype=np.float64).reshape(n, dim)


def rotation(angle: float) -> np.ndarray:
    """The 2x2 counter-clockwise rotation by `angle` radians."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s], [s, c]])


def rotation3(angle: float, axis: tuple[float, float, float]) -> np.ndarray:
    """The 3x3 rotation by `angle` radians about `axis` (right-hand rule; Rodrigues)."""
    u = np.asarray(axis, dtype=np.float64)
    u = u / np.linalg.norm(u)
    k = np.array([[0.0, -u[2], u[1]], [u[2], 0.0, -u[0]], [-u[1], u[0], 0.0]])
    return np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * (k @ k)
