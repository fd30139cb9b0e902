"""The lighting server's fixes (`frame_solver`): `receiver.locate.posefilter.solve_batch` with each
warm-started frame solved by the compiled kernel `receiver.serve._warm` (one frame at a time, a few
microseconds, so a datagram costs about the same alone as in a batch of 64, and its reply does not
depend on what it was batched with). Without the kernel (not built, or OCCLOC_PURE=1) it is
`solve_batch` itself, the numpy reference the kernel is tested against.

Imported by the server once its socket is bound (it pulls in the solver: start-up latency).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from receiver.core import native
from receiver.locate.lsq import BELOW_CEILING_M, LM_FTOL, LM_LAMBDA_MAX, Fix
from receiver.locate.pose import WARM_LAMBDA0, WARM_MAX_CHI2_DOF, WARM_XTOL, WarmProblem, solve_warm_batch
from receiver.locate.posefilter import solve_batch

KERNEL = "receiver.serve._warm"
# Solver rounds at most per warm fix (`receiver.locate.lsq.lm_batch`'s default).
MAX_ROUNDS = 100


def reference_problem(q: WarmProblem) -> WarmProblem:
    """q with `receiver.locate.pose.warm_problem`'s range rule applied (solver "auto"): a range
    counts where d and sigma_d are finite and sigma_d positive; the others are NaN with sigma 1."""
    has_d = np.isfinite(q.d) & np.isfinite(q.sigma_d) & (q.sigma_d > 0)
    return replace(q, d=np.where(has_d, q.d, np.nan), sigma_d=np.where(has_d, q.sigma_d, 1.0))


def warm_fix(kernel, q: WarmProblem, loss: str, f_scale: float) -> Fix | None:
    """`receiver.locate.pose.solve_warm_batch([q])[0]` by the compiled kernel: the fix when it
    explains its frame (converged, chi^2 / dof <= WARM_MAX_CHI2_DOF, camera below the LEDs), else
    None (solve from scratch). A frame the kernel leaves to numpy (`REFERENCE`: a loss it does not
    know, J^T J nearly singular) is solved by `solve_warm_batch`."""
    out = np.empty(21)
    status, chi2, dof, z_min, n_ranges = kernel.solve(
        q.L, q.uv, q.sigma_uv, q.d, q.sigma_d, q.up, q.up_sigma, q.R0, q.C0, loss, f_scale,
        WARM_XTOL, LM_FTOL, WARM_LAMBDA0, LM_LAMBDA_MAX, MAX_ROUNDS, out)
    if status == kernel.REFERENCE:
        return solve_warm_batch([reference_problem(q)], loss=loss, f_scale=f_scale)[0]
    if status != kernel.OK or chi2 > WARM_MAX_CHI2_DOF * max(dof, 1) or not out[2] <= z_min - BELOW_CEILING_M:
        return None
    return Fix(out[:3], out[12:].reshape(3, 3), out[3:12].reshape(3, 3), "range+angle" if n_ranges else "pnp",
               len(q.L), chi2, dof)


def frame_solver():
    """`solve_frames` bound to the compiled kernel, or `receiver.locate.posefilter.solve_batch`
    without it (not built, OCCLOC_PURE=1)."""
    kernel = native.load(KERNEL)
    if kernel is None:
        return solve_batch
    return lambda frames: solve_frames(frames, kernel)


def solve_frames(frames, kernel) -> list[Fix | None]:
    """`solve_batch(frames)` (each (pose_filter, t_s, L_map, uv, d, sigma_d, R_prior), at most one
    per filter), the warm-started frames by the kernel."""
    fixes: list[Fix | None] = [None] * len(frames)
    cold = []
    for i, (pf, *args) in enumerate(frames):
        q = pf.warm_problem(*args)
        fix = None if q is None else warm_fix(kernel, q, pf.loss, pf.f_scale)
        if fix is None:
            cold.append(i)
        fixes[i] = fix
    for i in cold:
        pf, *args = frames[i]
        fixes[i] = pf.solve_cold(*args)
    return fixes
