"""An independent numpy reference of Couzin's zone model (J. Theor. Biol. 218, 2002): O(N^2)
pair matrices, its own zones, noise and turn, sharing no code with the engine but the
counter-based uniforms (kernels.space.rng.uniform_np), replayed to compare noisy runs."""

from __future__ import annotations

import math

import numpy as np

from flocklab.kernels.space.rng import step_key, uniform_np


def _unit(a: np.ndarray) -> np.ndarray:
    return a / np.linalg.norm(a, axis=1, keepdims=True)


def frame(m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit vectors normal to each row of m: 2D m turned by +90 degrees; 3D b1 from e_x (e_y
    where |m_x| > 1/2) made normal to m, and b2 = m x b1."""
    if m.shape[1] == 2:
        return np.stack([-m[:, 1], m[:, 0]], axis=1), np.zeros_like(m)
    axis = np.zeros_like(m)
    axis[:, 0] = np.abs(m[:, 0]) <= 0.5
    axis[:, 1] = np.abs(m[:, 0]) > 0.5
    b1 = _unit(axis - (axis * m).sum(axis=1, keepdims=True) * m)
    return b1, np.cross(m, b1)


def desired(x: np.ndarray, e: np.ndarray, *, r_r: float, r_o: float, r_a: float,
            fov_deg: float, combine: str = "sum") -> np.ndarray:
    """Each agent's desired unit direction before noise (eqs. 1-3 and the combination)."""
    d = x[None, :, :] - x[:, None, :]  # d[i, j] = x_j - x_i
    r = np.sqrt((d**2).sum(axis=-1))
    with np.errstate(invalid="ignore", divide="ignore"):
        u = np.where(r[..., None] > 0, d / r[..., None], 0.0)
    other = r > 0
    cosang = (e[:, None, :] * u).sum(axis=-1)  # angle between e_i and r_ij
    seen = cosang >= math.cos(math.radians(fov_deg) / 2) if fov_deg < 360 else other
    zr = other & (r < r_r)
    zo = other & (r >= r_r) & (r < r_o) & seen
    za = other & (r >= r_o) & (r < r_a) & seen
    dr = -(zr[..., None] * u).sum(axis=1)
    do = zo.astype(float) @ e
    da = (za[..., None] * u).sum(axis=1)
    hr, ho, ha = zr.any(axis=1), zo.any(axis=1), za.any(axis=1)
    out = e.copy()
    out[ha] = da[ha]
    out[ho] = do[ho]
    both = ho & ha
    if combine == "unit":
        do = do / np.where(ho, np.linalg.norm(do, axis=1), 1.0)[:, None]
        da = da / np.where(ha, np.linalg.norm(da, axis=1), 1.0)[:, None]
    out[both] = 0.5 * (do[both] + da[both])
    out[hr] = dr[hr]
    n = np.linalg.norm(out, axis=1)
    out = np.where(n[:, None] > 0, out / np.where(n > 0, n, 1.0)[:, None], e)
    return out


def step(x: np.ndarray, e: np.ndarray, *, seed: int, step_no: int, r_r: float, dr_o: float,
         dr_a: float, field_of_view: float, turning_rate: float, speed: float, sigma: float,
         dt: float, combine: str = "sum") -> tuple[np.ndarray, np.ndarray]:
    """One synchronous step of every agent (x, e in agent-id order)."""
    n, dim = x.shape
    r_o = r_r + dr_o
    d = desired(x, e, r_r=r_r, r_o=r_o, r_a=r_o + dr_a, fov_deg=field_of_view,
                combine=combine)
    if sigma > 0:
        ids = np.arange(n)
        u1, u2, u3 = (uniform_np(step_key(seed, s, step_no), ids) for s in range(3))
        g = sigma * np.sqrt(-2.0 * np.log(1.0 - u1)) * np.cos(2 * np.pi * u2)
        b1, b2 = frame(d)
        b = b1 if dim == 2 else (np.cos(2 * np.pi * u3)[:, None] * b1
                                 + np.sin(2 * np.pi * u3)[:, None] * b2)
        d = np.cos(g)[:, None] * d + np.sin(g)[:, None] * b
    turn = math.radians(turning_rate) * dt
    c = (e * d).sum(axis=1)
    w = d - c[:, None] * e
    wn = np.linalg.norm(w, axis=1)
    w = np.where(wn[:, None] > 0, w / np.where(wn > 0, wn, 1.0)[:, None], frame(e)[0])
    turned = math.cos(turn) * e + math.sin(turn) * w
    new = np.where((c >= math.cos(turn))[:, None], d, turned)
    new = _unit(new)
    return x + speed * dt * new, new


def order_parameters(x: np.ndarray, e: np.ndarray) -> tuple[float, float]:
    """(p, m): |sum e_i| / N and |sum u_ic x e_i| / N (2D: the z component's magnitude)."""
    n, dim = x.shape
    r = x - x.mean(axis=0)
    nr = np.linalg.norm(r, axis=1)
    u = np.where(nr[:, None] > 0, r / np.where(nr > 0, nr, 1.0)[:, None], 0.0)
    if dim == 2:
        m = abs((u[:, 0] * e[:, 1] - u[:, 1] * e[:, 0]).sum()) / n
    else:
        m = float(np.linalg.norm(np.cross(u, e).sum(axis=0))) / n
    return float(np.linalg.norm(e.sum(axis=0))) / n, m
