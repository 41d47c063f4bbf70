"""Large-N frames as fields on a screen grid: the density (agents per unit area of the
picture; in 3D summed along the line of sight) or the local polarization |sum_i e_i| / n
of each cell's n agents (their 3D headings in 3D), with the cells' mean heading, as seen
on the screen, as a coarse arrow field.

Agents are binned once, by integer arithmetic and `np.bincount` (a fraction of
`np.histogram2d`'s cost, which searches the bin edges anew for every weight); the coarse
grid's sums are the fine grid's summed over blocks of cells.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .projection import Camera

FIELD_BINS = 160  # grid cells along each side of a field picture
COARSE_ARROWS = 20  # mean-heading arrows along each side (FIELD_BINS is a multiple)
Limits = tuple[float, float, float, float]


def field_artists(ax: Any, cax: Any, mode: str, limits: Limits, camera: Camera
                  ) -> tuple[Any, Any]:
    """The field's image with its colour bar, and the coarse arrows, both still empty."""
    from matplotlib.colors import LogNorm

    x0, x1, y0, y1 = limits
    blank = np.ma.masked_all((FIELD_BINS, FIELD_BINS))
    if mode == "density":
        im = ax.imshow(blank, origin="lower", extent=(x0, x1, y0, y1), cmap="magma",
                       norm=LogNorm(1.0, 10.0), interpolation="nearest", aspect="auto")
        label = ("agents per unit area (seen through the depth)" if camera.is_3d
                 else "agents per unit area")
    else:
        im = ax.imshow(blank, origin="lower", extent=(x0, x1, y0, y1), cmap="viridis",
                       vmin=0, vmax=1, interpolation="nearest", aspect="auto")
        label = "local polarization"
    cax.figure.colorbar(im, cax=cax).set_label(label)
    # empty cells show the background: black (no density) under white arrows, or grey
    # (no polarization defined) under black arrows
    ax.set_facecolor("black" if mode == "density" else "0.82")
    m = COARSE_ARROWS
    xe, ye = np.linspace(x0, x1, m + 1), np.linspace(y0, y1, m + 1)
    xc, yc = np.meshgrid((xe[:-1] + xe[1:]) / 2, (ye[:-1] + ye[1:]) / 2, indexing="ij")
    zeros = np.zeros(m * m)
    coarse = ax.quiver(xc.ravel(), yc.ravel(), zeros, zeros,
                       color="white" if mode == "density" else "black", angles="xy",
                       scale_units="xy", scale=1.0, width=0.003, alpha=0.9, zorder=4,
                       minlength=0)  # an empty cell draws nothing, not a dot
    return im, coarse


def field_data(screen_pos: np.ndarray, directions: np.ndarray, mode: str, limits: Limits,
               camera: Camera) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]:
    """The density or local polarization on FIELD_BINS x FIELD_BINS cells (indexed
    [x, y], empty cells masked), and the coarse arrows' components (zero where no agent
    is). `screen_pos` (N, 2) are the agents' pictures, `directions` (N, dim) their unit
    headings."""
    x0, x1, y0, y1 = limits
    n = FIELD_BINS
    cell = _cell_index(screen_pos, limits, n)
    inside = cell >= 0
    cell = cell[inside]
    counts = np.bincount(cell, minlength=n * n).reshape(n, n).astype(np.float64)
    sums = np.stack([np.bincount(cell, weights=directions[inside, i], minlength=n * n)
                     for i in range(directions.shape[1])], axis=-1).reshape(n, n, -1)
    if mode == "density":
        area = ((x1 - x0) / n) * ((y1 - y0) / n)
        image = np.ma.masked_equal(counts, 0) / area
    else:
        with np.errstate(invalid="ignore", divide="ignore"):
            image = np.ma.masked_invalid(np.sqrt((sums * sums).sum(axis=-1)) / counts)
    m, k = COARSE_ARROWS, FIELD_BINS // COARSE_ARROWS
    coarse_counts = counts.reshape(m, k, m, k).sum(axis=(1, 3))
    coarse_sums = camera.screen(sums.reshape(m, k, m, k, -1).sum(axis=(1, 3)))
    step = (x1 - x0) / m * 0.8
    mean = coarse_sums / np.maximum(coarse_counts, 1)[..., None] * step
    return image, (mean[..., 0].ravel(), mean[..., 1].ravel())


def _cell_index(xy: np.ndarray, limits: Limits, n: int) -> np.ndarray:
    """Each point's cell ix * n + iy on an n x n grid over the limits, -1 outside (the
    upper edges count as inside, as in np.histogram2d)."""
    x0, x1, y0, y1 = limits
    with np.errstate(invalid="ignore"):  # a non-finite position falls outside
        ix = np.floor((xy[:, 0] - x0) * (n / (x1 - x0))).astype(np.int64)
        iy = np.floor((xy[:, 1] - y0) * (n / (y1 - y0))).astype(np.int64)
    ix[xy[:, 0] == x1] = n - 1
    iy[xy[:, 1] == y1] = n - 1
    ok = (ix >= 0) & (ix < n) & (iy >= 0) & (iy < n)
    return np.where(ok, ix * n + iy, -1)
