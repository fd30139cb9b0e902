"""`PoseFilter` with its per-frame arithmetic compiled, for the receiver's positioner
(receiver.locate.indoor) and the lighting server's devices (receiver.serve.devices): the Kalman
steps (`FastKalman`: receiver/locate/_kalman.pyx, the same equations as `PositionKalman`, summed
in another order: states equal to rounding) and the INTERFACES.md `position` object built from
plain floats (`position_object`; compiled, with the rounding in C: receiver/locate/_position.pyx,
tested equal to it key for key and bit for bit) instead of PoseFilter.update's ~20 numpy calls
and ~20 Python `round`s per frame (on the synthetic 16-LED scene 0.42 -> 0.05 M instructions a
frame). `pose_filter_class()` is `CompiledPoseFilter` when the kernel is built, else `PoseFilter`
itself (OCCLOC_PURE=1: the reference the tests compare with).
"""

from __future__ import annotations

import math

import numpy as np

from receiver.core import native
from receiver.locate.kalman import PositionKalman
from receiver.locate.posefilter import PoseFilter

KERNEL = "receiver.locate._kalman"
POSITION_KERNEL = "receiver.locate._position"


class FastKalman(PositionKalman):
    """`PositionKalman` whose predict / update / gate arithmetic is `receiver.locate._kalman`
    (in place on the same (6, 1) state and (6, 6) covariance); the filter logic (gate, restarts,
    coasting) is PositionKalman's."""

    def __init__(self, kernel, **kwargs):
        super().__init__(**kwargs)
        self._k = kernel

    def _predict(self, dt: float) -> None:
        self._k.predict(self._x, self._P, dt, self.q)

    def _update(self, z: np.ndarray, R: np.ndarray) -> None:
        if not self._k.update(self._x, self._P, z, R):
            raise np.linalg.LinAlgError("singular innovation covariance")

    def _mahalanobis2(self, z: np.ndarray, R: np.ndarray) -> float:
        m2 = self._k.mahalanobis2(self._x, self._P, z, R)
        if math.isnan(m2):
            raise np.linalg.LinAlgError("singular innovation covariance")
        return m2

    def _predicted(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """`PositionKalman._predicted` by the compiled predict step on copies of the state."""
        x, P = self._x.copy(), self._P.copy()
        self._k.predict(x, P, dt, self.q)
        return x.reshape(6), P


class CompiledPoseFilter(PoseFilter):
    """`PoseFilter` with a `FastKalman` and `update` building the position object from plain
    floats (`position_object`, or the compiled `position_kernel`: the same dict; a left-handed
    map's mirrored numbers are left to PoseFilter)."""

    def __init__(self, *, kernel, position_kernel=None, **kwargs):
        self._kernel, self._position = kernel, position_kernel
        super().__init__(**kwargs)

    def _restart(self) -> None:
        super()._restart()
        if self.kf is not None:
            self.kf = FastKalman(self._kernel, **self._kalman_args)

    def _step(self, t_s: float, fix):
        """`PoseFilter.update`'s state change: the filter state (x, P) or None."""
        if fix is not None:
            self.n_fixes += 1
            self._C, self._t_C = fix.C, t_s
            if fix.R_cw is not None:
                self.keep_orientation(t_s, fix.R_cw)
        if self.kf is None:
            return None
        return self.kf.step(t_s, None if fix is None else fix.C, None if fix is None else fix.cov)

    def _position_args(self, state, fix, n_leds: int) -> tuple:
        x, P = (None, None) if state is None else state
        return (x, P, *((None, None, None) if fix is None else (fix.C, fix.cov, fix.R_cw)),
                "kalman-coast" if fix is None else fix.method, n_leds,
                None if self.handedness_source == "default" else self.handedness)

    def update(self, t_s: float, fix, n_leds: int) -> dict | None:
        if self.mirrored:
            return super().update(t_s, fix, n_leds)
        state = self._step(t_s, fix)
        if fix is None and state is None:
            return None
        if self._position is None:
            handedness = None if self.handedness_source == "default" else self.handedness
            return position_object(state, fix, n_leds, handedness)
        return self._position.position(*self._position_args(state, fix, n_leds))


def np_round(v: float, scale: float) -> float:
    """numpy's `round` of a float to log10(scale) decimals: rint(v * scale) / scale (half to even,
    the sign of a zero kept; NaN and infinities stay, as in numpy: the reply's encoding refuses
    them)."""
    y = v * scale
    if not math.isfinite(y):
        return y / scale
    return math.copysign(round(y) / scale, y)


def _std(cov: list) -> list[float]:
    """`receiver.locate.kalman.position_std` (rounded to 5 decimals) of a nested-list covariance."""
    return [round(math.sqrt(max(0.0, cov[i][i])), 5) for i in range(3)]


def _xyz(v: list) -> dict:
    return {"x": round(v[0], 5), "y": round(v[1], 5), "z": round(v[2], 5)}


def ypr_deg(R: list) -> tuple[float, float, float]:
    """`receiver.locate.pose.rotation_to_ypr_deg` of a nested-list R_cw: the same arithmetic on
    M = R^T CAM_TO_BODY^T, whose entries are entries of R or their negatives (M[i] = (R[2][i],
    -R[0][i], -R[1][i]): CAM_TO_BODY holds only 0 and +-1, so numpy's product is exact)."""
    theta = math.asin(max(-1.0, min(1.0, -R[2][2])))
    if abs(math.cos(theta)) < 1e-6:
        yaw, roll = math.atan2(R[0][0], -R[0][1]), 0.0
    else:
        yaw, roll = math.atan2(R[2][1], R[2][0]), math.atan2(-R[0][2], -R[1][2])
    return math.degrees(yaw), -math.degrees(theta), math.degrees(roll)


def position_object(state, fix, n_leds: int, handedness: str | None) -> dict:
    """`PoseFilter.update`'s INTERFACES.md position object of a right-handed solving frame (the
    map's): the filter state (x (6,), P (6, 6)) or None, the frame's fix or None."""
    if state is not None:
        x = state[0].tolist()
        P3 = state[1][:3, :3].tolist()
        pos = _xyz(x)
        pos.update(method=fix.method if fix is not None else "kalman-coast", n_leds=n_leds, filtered=True,
                   std_m=_std(P3), cov=[[np_round(v, 1e8) for v in row] for row in P3],
                   velocity_mps=[round(v, 4) for v in x[3:]])
    else:
        pos = _xyz(fix.C.tolist())
        pos.update(method=fix.method, n_leds=n_leds, filtered=False)
    if fix is not None:
        pos["raw"] = _xyz(fix.C.tolist())
        pos["raw_std_m"] = _std(fix.cov.tolist())
        if fix.R_cw is not None:
            R = fix.R_cw.tolist()
            pos["R_wc"] = [[np_round(R[j][i], 1e6) for j in range(3)] for i in range(3)]
            yaw, pitch, roll = ypr_deg(R)
            pos.update(yaw_deg=round(yaw, 3), pitch_deg=round(pitch, 3), roll_deg=round(roll, 3))
    else:
        pos["raw"] = None
    if handedness is not None:
        pos["handedness"] = handedness
    return pos


def pose_filter_class(cls=None):
    """A factory of `cls` (default `CompiledPoseFilter`) bound to the compiled kernels, or
    `PoseFilter` itself without them; called with PoseFilter's keyword arguments."""
    kernel = native.load(KERNEL)
    if kernel is None:
        return PoseFilter
    position_kernel = native.load(POSITION_KERNEL)
    cls = cls or CompiledPoseFilter

    def make(**kwargs) -> PoseFilter:
        return cls(kernel=kernel, position_kernel=position_kernel, **kwargs)
    return make
