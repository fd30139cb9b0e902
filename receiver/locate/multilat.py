"""Ranges-only camera centre (thesis eqs. 26-34): the linear system of eq. 27, the null-space
roots of eqs. 29-31 for LEDs on one ceiling (mirror above the ceiling rejected), then a robust
weighted refinement.
"""

from __future__ import annotations

import math

import numpy as np
from receiver.locate.lsq import DEFAULT_F_SCALE, DEFAULT_LOSS, _covariance
from receiver.locate.lsq import BELOW_CEILING_M, Fix


# Relative singular value below which eq. 27's matrix counts as rank deficient.
RANK_TOL = 1e-6


# ---------------------------------------------------------------- multilateration, eqs. 26-34

def multilaterate_linear(L: np.ndarray, d: np.ndarray) -> list[np.ndarray]:
    """Candidate camera centres (3,) from LED positions L (N, 3) and ranges d (N,), eqs. 27-34.
    Rank 4: the single least-squares solution (eq. 34). Rank 3 (LEDs on one plane): the two roots
    of eqs. 30-31. Fewer (collinear LEDs, eq. 32 leaves a free parameter): no candidates."""
    L = np.asarray(L, float)
    d = np.asarray(d, float)
    Z0 = np.column_stack([np.ones(len(L)), -2 * L])                 # eq. 27 / 28
    q0 = d ** 2 - np.sum(L ** 2, axis=1)
    _, s, Vt = np.linalg.svd(Z0)
    rank = int(np.sum(s > RANK_TOL * s[0]))
    if rank >= 4 and len(L) >= 4:
        x = np.linalg.lstsq(Z0, q0, rcond=None)[0]                  # eq. 34
        return [x[1:]]
    if rank != 3:
        return []
    xp = np.linalg.pinv(Z0, rcond=RANK_TOL) @ q0                    # particular solution
    xh = Vt[3]                                                      # homogeneous solution
    # x = xp + eps xh (eq. 29) must satisfy x0 = x1^2 + x2^2 + x3^2.
    a = float(xh[1:] @ xh[1:])
    b = float(2 * xp[1:] @ xh[1:] - xh[0])
    c = float(xp[1:] @ xp[1:] - xp[0])
    if a < 1e-15:
        return []
    disc = b * b - 4 * a * c
    # Noisy ranges can make the roots complex: the closest real point is the double root.
    roots = [(-b - math.sqrt(disc)) / (2 * a), (-b + math.sqrt(disc)) / (2 * a)] if disc > 0 else [-b / (2 * a)]
    return [(xp + e * xh)[1:] for e in roots]                       # eqs. 30-31


def multilaterate(L: np.ndarray, d: np.ndarray, sigma_d: np.ndarray, *, loss: str = DEFAULT_LOSS,
                  f_scale: float = DEFAULT_F_SCALE, C0: np.ndarray | None = None) -> Fix | None:
    """Ranges-only camera centre: eqs. 27-34 then robust weighted refinement, camera below the
    LEDs. `C0` (3,) optional prior used when the linear system has no solution."""
    L = np.asarray(L, float)
    d = np.asarray(d, float)
    w = 1.0 / np.asarray(sigma_d, float)
    if len(L) < 3:
        return None
    z_ceiling = float(L[:, 2].min())
    cands = multilaterate_linear(L, d)
    if C0 is not None:
        cands.append(np.asarray(C0, float))
    if not cands:
        return None

    def fun(C):
        return (np.linalg.norm(L - C, axis=1) - d) * w

    best = None
    for C in cands:
        if C[2] > z_ceiling:                        # start from the mirror image's twin
            C = C.copy()
            C[2] = 2 * z_ceiling - C[2]
        if C[2] > z_ceiling - BELOW_CEILING_M:
            C = C.copy()
            C[2] = z_ceiling - float(np.median(d))
        from scipy.optimize import least_squares  # lazy: scipy.optimize costs ~0.8 s to import (a stream preloads it: receiver.vision.track.preload)
        res = least_squares(fun, C, loss=loss, f_scale=f_scale, method="trf")
        Cr = res.x
        if Cr[2] > z_ceiling - BELOW_CEILING_M:     # mirror solution above the ceiling: rejected
            continue
        if best is None or res.cost < best[1]:
            best = (Cr, res.cost)
    if best is None:
        return None
    cov, chi2, dof = _covariance(fun, best[0])
    return Fix(best[0], cov, None, "multilateration", len(L), chi2, dof)
