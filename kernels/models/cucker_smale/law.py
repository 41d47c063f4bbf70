"""The Cucker–Smale law (IEEE TAC 52(5), 2007), written once for every schedule (the
per-step kernels of step.py, the fused one of fused.py) as functions of values; how an
agent's partners are gathered (all pairs, the grid's 3x3 cells) is the schedule's.

For agent i at x_i with velocity v_i:
  psi(r) = K / (sigma^2 + r^2)^beta                     (the paper's a_ij, K = H)
  w_ij = psi(|x_j - x_i|) [|x_j - x_i| < cutoff]        (all-to-all: no bracket)
  S_i = (sum_j w_ij (v_j - v_i), sum_j w_ij)            (j over every agent, i included:
                                                         its velocity term is 0)
  u_i = lambda S_i[:d] / D_i, D_i = N (mean), 1 (sum), S_i[d] (local: Motsch–Tadmor)
  semi-implicit Euler: v_i' = v_i + dt u_i, x_i' = x_i + dt v_i'.
  observed: max_ij |v_i - v_j|, max_ij |x_i - x_j| (`spread`), the mean velocity.
The velocity difference is summed (not sum w v_j - v_i sum w), so a settled flock's
u_i is its rounding, not the cancellation of two large sums.
"""

import numpy as np
import taichi as ti

from ...space.grid import within
from ...space.params import Slots

# The law's runtime parameters (a small float array; the functions below take them as a
# vector q, read once per agent): K, sigma^2, -beta, lambda, the cutoff squared
# (all-to-all: +inf), the normalising D of mean/sum (N or 1), dt.
P = Slots("K", "SIGMA2", "NEG_BETA", "COUPLING", "CUT2", "NORM", "DT")
NORMALIZATIONS = ("mean", "sum", "local")
# Why a Cucker–Smale step blew up, as every schedule words it.
DIVERGED_CAUSE = "dt too large for the coupling (see the schema's stability bound)"


def parameters(p, n: int, dt: float) -> np.ndarray:
    """The runtime parameter vector of model block `p` at N = n."""
    norm = float(n) if p.normalization == "mean" else 1.0
    cut2 = float("inf") if p.cutoff is None else p.cutoff * p.cutoff
    return P.pack(K=p.K, SIGMA2=p.sigma * p.sigma, NEG_BETA=-p.beta, COUPLING=p.coupling,
                  CUT2=cut2, NORM=norm, DT=dt)


@ti.func
def load(prm: ti.template()):
    """The parameter vector q from a (P.size,) array."""
    return ti.Vector([prm[c] for c in ti.static(range(P.size))], dt=float)


@ti.func
def psi(r2, q):
    """psi at squared distance r2: K (sigma^2 + r^2)^(-beta). The common betas take square
    roots or a division instead of pow (exp and log: most of a step's cost), each within an
    ulp or two of it: beta = 0 gives K exactly, 1/4 K / sqrt(sqrt(x)), 1/2 K / sqrt(x), 1
    K / x. The branch is the same for every pair of a run, so it predicts."""
    x = q[P.SIGMA2] + r2
    nb = q[P.NEG_BETA]
    w = q[P.K]
    if nb == -0.25:
        w = q[P.K] / ti.sqrt(ti.sqrt(x))
    elif nb == -0.5:
        w = q[P.K] / ti.sqrt(x)
    elif nb == -1.0:
        w = q[P.K] / x
    elif nb != 0.0:
        w = q[P.K] * ti.pow(x, nb)
    return w


@ti.func
def weight(r2, q):
    """w_ij at squared distance r2: psi inside the cutoff (|d| < cutoff), else 0."""
    w = 0.0
    if within(r2, q[P.CUT2], False):
        w = psi(r2, q)
    return w


@ti.func
def pair_term(acc, d, vj, vi, q):
    """acc plus agent j's term (w (v_j - v_i), w), d = x_j - x_i; w = 0 from the cutoff
    on (strictly: |d| < cutoff interacts). psi only inside the cutoff: its pow is most of
    a step (branch-free, psi for every candidate, the step at 10^5 took 2.3x longer)."""
    dim = ti.static(d.n)
    r2 = d.dot(d)
    if within(r2, q[P.CUT2], False):
        w = psi(r2, q)
        for c in ti.static(range(dim)):
            acc[c] += w * (vj[c] - vi[c])
        acc[dim] += w
    return acc


@ti.func
def mutual_term(d, vj, vi, q, cut: ti.template()):
    """The pair (i, j) once, for both (psi is symmetric): (w, w (v_j - v_i)); agent i adds
    the term, agent j subtracts it, both add w to their D. `cut` (compile-time): whether
    there is a cutoff to test (all-to-all: psi for every pair)."""
    r2 = d.dot(d)
    w = 0.0
    if ti.static(cut):
        w = weight(r2, q)
    else:
        w = psi(r2, q)
    return w, w * (vj - vi)


@ti.func
def acceleration(acc, q, local: ti.template()):
    """u_i = lambda S_i[:d] / D_i from agent i's sums (local: D_i = sum_j w_ij)."""
    dim = ti.static(acc.n - 1)
    den = q[P.NORM]
    if ti.static(local):
        den = acc[dim]
    f = q[P.COUPLING] / den
    return ti.Vector([f * acc[c] for c in ti.static(range(dim))])


@ti.func
def spread(acc, vi, vj, xi, xj):
    """acc = (max |v_i - v_j|^2, max |x_i - x_j|^2) folded over the pair (i, j): the
    squared velocity and position diameters (observe.py streams the same definitions
    through convex hulls on the host)."""
    dv = vj - vi
    dx = xj - xi
    return ti.max(acc, ti.math.vec2(dv.dot(dv), dx.dot(dx)))


@ti.func
def euler(xi, vi, u, dt):
    """Semi-implicit Euler: (x', v') = (x + dt v', v + dt u)."""
    v = vi + dt * u
    return xi + dt * v, v
