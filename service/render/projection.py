"""How a run is seen: the plane as it is, 3D space through a fixed orthographic camera.

A 3D point p is drawn at screen (p . r, p . u) with depth p . e, where the viewer looks
from azimuth phi and elevation theta (matplotlib's mplot3d convention):

    e = (cos theta cos phi, cos theta sin phi, sin theta)    towards the viewer
    r = (-sin phi, cos phi, 0)                               screen right
    u = e x r = (-sin theta cos phi, -sin theta sin phi, cos theta)   screen up

The projection is linear, so a segment's picture is the segment between its ends'
pictures, a vector (a velocity, an offset b_i) projects the same way, and a sphere of
radius rho projects to the disc of radius rho about its centre's picture (M3's spheres
are exact circles). Depth is shown by drawing far agents first, paler (mixed towards
white, "aerial perspective") and smaller, and the box's hidden edges dashed.
"""

from __future__ import annotations

import math
from itertools import product

import numpy as np

ELEVATION_DEG = 30.0  # matplotlib's mplot3d default view
AZIMUTH_DEG = -60.0
FOG = 0.7  # the farthest agents are mixed this far towards white
NEAR_SIZE, FAR_SIZE = 1.35, 0.6  # marker area factors at the nearest and farthest depth


class Camera:
    """The identity in 2D; in 3D the orthographic view of the module docstring."""

    def __init__(self, dim: int, elevation_deg: float = ELEVATION_DEG,
                 azimuth_deg: float = AZIMUTH_DEG):
        self.dim = dim
        th, ph = math.radians(elevation_deg), math.radians(azimuth_deg)
        self.eye = np.array([math.cos(th) * math.cos(ph), math.cos(th) * math.sin(ph),
                             math.sin(th)])
        right = np.array([-math.sin(ph), math.cos(ph), 0.0])
        up = np.cross(self.eye, right)
        self.axes = np.column_stack([right, up])  # (3, 2): screen = p @ axes
        self.elevation_deg, self.azimuth_deg = elevation_deg, azimuth_deg

    @property
    def is_3d(self) -> bool:
        return self.dim == 3

    def screen(self, p: np.ndarray) -> np.ndarray:
        """(..., dim) points or vectors to (..., 2) screen coordinates."""
        return p @ self.axes if self.is_3d else p

    def depth(self, p: np.ndarray) -> np.ndarray:
        """(..., dim) to (...): larger is nearer the viewer (0 in the plane)."""
        return p @ self.eye if self.is_3d else np.zeros(p.shape[:-1])

    def describe(self) -> str:
        return (f"3D, seen from azimuth {self.azimuth_deg:g}°, elevation "
                f"{self.elevation_deg:g}°")


def nearness(depth: np.ndarray, far: float, near: float) -> np.ndarray:
    """Depth as 0 (the view's farthest) .. 1 (its nearest)."""
    span = near - far
    if span <= 0:
        return np.ones_like(depth)
    return np.clip((depth - far) / span, 0.0, 1.0)


def fogged(rgba: np.ndarray, near01: np.ndarray) -> np.ndarray:
    """RGBA colours mixed towards white by FOG at the far end, untouched at the near end."""
    out = rgba.copy()
    f = (FOG * (1.0 - near01))[:, None]
    out[:, :3] += (1.0 - out[:, :3]) * f
    return out


def marker_scale(near01: np.ndarray) -> np.ndarray:
    return FAR_SIZE + (NEAR_SIZE - FAR_SIZE) * near01


def box_corners(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """The 8 corners of the box lo..hi, (8, 3), corner index bits (x, y, z)."""
    return np.array([[(lo, hi)[b][i] for i, b in enumerate(bits)]
                     for bits in product((0, 1), repeat=3)])


def box_edges(lo: np.ndarray, hi: np.ndarray, camera: Camera
              ) -> tuple[np.ndarray, np.ndarray]:
    """The 12 edges of the box as (12, 2, 3) segments, and which of them are hidden: the
    three that meet at the corner farthest from the viewer (a convex box's back)."""
    corners = box_corners(lo, hi)
    pairs = [(a, b) for a in range(8) for b in range(a + 1, 8)
             if bin(a ^ b).count("1") == 1]
    far = int(np.argmin(camera.depth(corners)))
    segments = np.array([[corners[a], corners[b]] for a, b in pairs])
    hidden = np.array([far in (a, b) for a, b in pairs])
    return segments, hidden
