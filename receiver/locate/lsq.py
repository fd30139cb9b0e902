"""Least squares shared by the solvers: a small robust Levenberg-Marquardt over a batch of
problems (`lm_batch`: IRLS with scipy's loss definitions), the fix covariance from the whitened Jacobian (`_covariance`),
and the unfiltered solution record `Fix`.

Fix covariance: ``cov = s^2 (J^T J)^-1`` at the solution, ``s^2 = max(1, chi^2/dof)``.
"""

from __future__ import annotations


from dataclasses import dataclass

import numpy as np

# Robust loss of the nonlinear refinements; residuals are whitened, so f_scale is in sigmas.
DEFAULT_LOSS = "soft_l1"
DEFAULT_F_SCALE = 3.0


def _jacobian(fun, p: np.ndarray, step: float = 1e-6) -> np.ndarray:
    """Central-difference Jacobian of fun at p (unmodified by any robust loss)."""
    f0 = fun(p)
    J = np.empty((len(f0), len(p)))
    for i in range(len(p)):
        dp = np.zeros_like(p)
        dp[i] = step
        J[:, i] = (fun(p + dp) - fun(p - dp)) / (2 * step)
    return J


# Robust losses the small solver below implements: rho(z) with z = (r / f_scale)^2 and its
# derivative, the IRLS weight (scipy.optimize.least_squares' definitions).
_LOSSES = {
    "linear": (lambda z: z, lambda z: np.ones_like(z)),
    "soft_l1": (lambda z: 2.0 * (np.sqrt(1.0 + z) - 1.0), lambda z: 1.0 / np.sqrt(1.0 + z)),
    "cauchy": (np.log1p, lambda z: 1.0 / (1.0 + z)),
    "huber": (lambda z: np.where(z <= 1.0, z, 2.0 * np.sqrt(z) - 1.0),
              lambda z: np.where(z <= 1.0, 1.0, 1.0 / np.sqrt(np.maximum(z, 1.0)))),
}
# Levenberg-Marquardt damping bounds and stopping rule (a relative step below
# LM_XTOL or a relative cost decrease below LM_FTOL: `lm_batch`, receiver/locate/_pnp.pyx).
LM_LAMBDA0, LM_LAMBDA_MAX = 1e-3, 1e8
LM_XTOL = 1e-8     # relative step
LM_FTOL = 1e-8     # relative cost decrease (scipy's ftol)


def _loss_cost(rho, r: np.ndarray, f_scale: float):
    """(cost, z) of whitened residuals r (..., M): sum rho(z) * f_scale^2 / 2 over the last axis
    with z = (r / f_scale)^2 (scipy.optimize.least_squares' robust cost)."""
    z = (r / f_scale) ** 2
    return 0.5 * f_scale ** 2 * rho(z).sum(axis=-1), z


def covariance_at(r: np.ndarray, J: np.ndarray, n_params: int) -> tuple[np.ndarray, float, int]:
    """(cov, chi2, dof) of a solution from its whitened residuals r and Jacobian J (module doc)."""
    dof = len(r) - n_params
    chi2 = float(r @ r)
    s2 = max(1.0, chi2 / dof) if dof > 0 else 1.0
    return np.linalg.pinv(J.T @ J) * s2, chi2, dof


def _covariance(fun, p: np.ndarray) -> tuple[np.ndarray, float, int]:
    r = fun(p)
    J = fun.jac(p) if hasattr(fun, "jac") else _jacobian(fun, p)
    return covariance_at(r, J, len(p))


# A camera centre must be at least this far below the lowest LED (m) -- mirror rejection.
BELOW_CEILING_M = 0.01


@dataclass(frozen=True)
class Fix:
    """One frame's unfiltered solution. `C` (3,) world m; `cov` (3, 3) m^2; `R_cw` (3, 3) or None
    when the solver yields no orientation; `chi2` of the whitened residuals and its `dof`."""

    C: np.ndarray
    cov: np.ndarray
    R_cw: np.ndarray | None
    method: str
    n_leds: int
    chi2: float = 0.0
    dof: int = 0


# ---------------------------------------------------------------- many small problems at once

def lm_batch(fun_jac, step, state, p_norm, *, loss: str = DEFAULT_LOSS, f_scale: float = DEFAULT_F_SCALE,
             xtol: float = LM_XTOL, ftol: float = LM_FTOL, lam0: float = LM_LAMBDA0, max_rounds: int = 100):
    """Levenberg-Marquardt on B independent problems at once, each with its own damping and
    stopping (a relative step below `xtol` -- then the problem stops where
    it is, without evaluating that step: nothing is left to gain -- or a kept step's relative
    cost decrease below `ftol`), so that numpy's per-call overhead is paid once per round for all
    of them. `lam0`: the initial damping (relative to
    the normal matrix' diagonal).

    The cost is sum rho((r/f_scale)^2) with scipy's losses, minimised through iteratively
    reweighted normal equations (weights rho'(z)). (scipy's curvature-corrected weights
    rho' + 2 z rho'' took 7 rounds on average from the lighting server's warm starts, these 4.)
    `state`: the B problems' parameters in the caller's form (e.g. a tuple of stacked arrays);
    `fun_jac(state) -> (r (B, M), J (B, M, P))` whitened residuals and their Jacobian with
    respect to a local step; `step(state, dp (B, P)) -> state` with dp applied (rows of dp are
    zero where nothing is to change); `p_norm(state) -> (B,)` the parameter norm of the relative
    step test. Residual rows that are all zero (padding) change nothing.
    A round tries one damped step for every unfinished problem: kept where the cost does not grow
    (damping / 10), else the damping * 10. Returns (state, r, J, ok (B,)):
    ok False where `max_rounds` ran out or the normal equations were singular."""
    rho, wfun = _LOSSES[loss]

    def cost_z(r):
        return _loss_cost(rho, r, f_scale)

    def select(keep, new, old):
        if keep.all():
            return new
        if not keep.any():
            return old
        return tuple(np.where(keep.reshape((-1,) + (1,) * (a.ndim - 1)), a, b) for a, b in zip(new, old))

    r, J = fun_jac(state)
    c, z = cost_z(r)
    B, _, P = J.shape
    lam = np.full(B, lam0)
    active = np.ones(B, bool)
    diag = np.arange(P)
    Jt = J.transpose(0, 2, 1)
    for _ in range(max_rounds):
        w = wfun(z)
        A = np.matmul(Jt, J * w[:, :, None])
        g = np.matmul(Jt, (w * r)[:, :, None])
        A[:, diag, diag] += lam[:, None] * np.maximum(A[:, diag, diag], 1e-12)
        try:
            dp = np.linalg.solve(A, -g)[:, :, 0]
        except np.linalg.LinAlgError:
            return state, r, J, ~active
        small = np.sqrt(np.einsum("bp,bp->b", dp, dp)) <= xtol * (1.0 + p_norm(state))
        if small.all() or not (active & ~small).any():   # nothing left to gain: done here
            return state, r, J, np.ones(B, bool)
        if not active.all():
            dp[~active] = 0.0
        trial = step(state, dp)
        r_new, J_new = fun_jac(trial)
        c_new, z_new = cost_z(r_new)
        accept = active & (c_new <= c) & ~small
        stop = small | (accept & (c - c_new <= ftol * c))
        state = select(accept, trial, state)
        r, J, c, z = select(accept, (r_new, J_new, c_new, z_new), (r, J, c, z))
        Jt = J.transpose(0, 2, 1)
        lam = np.maximum(lam * np.where(accept, 0.1, 10.0), 1e-12)
        active &= ~(stop | (lam > LM_LAMBDA_MAX))
        if not active.any():
            return state, r, J, np.ones(B, bool)
    return state, r, J, ~active


def covariance_batch(r: np.ndarray, J: np.ndarray, dof: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`covariance_at` of B problems: r (B, M), J (B, M, P), dof (B,) -> (cov (B, P, P), chi2 (B,))."""
    chi2 = np.einsum("bm,bm->b", r, r)
    s2 = np.where(dof > 0, np.maximum(1.0, chi2 / np.maximum(dof, 1)), 1.0)
    return np.linalg.pinv(np.matmul(J.transpose(0, 2, 1), J)) * s2[:, None, None], chi2
