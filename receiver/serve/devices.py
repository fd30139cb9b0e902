"""The lighting server's per-device state: `receiver.locate.posefilter.PoseFilter` (as the
receiver's positioner runs it) with the server's warm-start problem and its reply JSON written by
the position kernel (`ServerPoseFilter`).

Imported by the server once its socket is bound (it pulls in the solver: start-up latency).
"""

from __future__ import annotations

import math

import numpy as np

from receiver.locate import _position
from receiver.locate.posefilter import PoseFilter
from receiver.locate.pose import WarmProblem, _is_collinear_cached
from receiver.locate.ranging import R_LOOKING_UP


class ServerPoseFilter(PoseFilter):
    """`PoseFilter` with the server's warm-start problem and reply JSON."""

    def warm_problem(self, t_s: float, L_map: np.ndarray, uv: np.ndarray | None, d: np.ndarray,
                     sigma_d: np.ndarray, R_prior: np.ndarray | None = None) -> WarmProblem | None:
        """`PoseFilter.warm_problem` for the server's arrays (L_map (n, 3), uv (n, 2), d and
        sigma_d (n,) float64) in a right-handed map with the default solver: the same problem,
        its arrays passed as they are (d / sigma_d unfiltered: `fixes.warm_fix` applies
        `receiver.locate.pose.warm_problem`'s range rule itself, also when it hands the frame to
        numpy, `fixes.reference_problem`); anything else is PoseFilter's."""
        if self.mirrored or self.solver != "auto" or uv is None:
            return super().warm_problem(t_s, L_map, uv, d, sigma_d, R_prior)
        if not self.warm_start or R_prior is None or self.handedness_source == "default" or self.track_prior:
            return None
        C0 = self.kf.predict_position(t_s) if self.kf is not None else None
        if C0 is None and self._t_C is not None and 0 <= t_s - self._t_C <= self.max_coast_s:
            C0 = self._C
        if C0 is None or len(L_map) < 3 or _is_collinear_cached(L_map.tobytes()):
            return None
        up = None if self.tilt_prior != "up" else R_LOOKING_UP[:, 2]
        return WarmProblem(L_map, uv, self.sigma_uv, d, sigma_d, up, math.radians(self.tilt_sigma_deg), R_prior, C0)

    def rotation_json(self, R: np.ndarray) -> bytes:
        """`wire.encode(R.tolist())`; a NaN or infinity: ValueError."""
        return _position.rotation_json(R)

    def update_json(self, t_s: float, fix, n_leds: int) -> bytes | None:
        """`update`, its position object encoded (`wire.encode`'s bytes), or None; a NaN or
        infinity in it: ValueError."""
        state = self._step(t_s, fix)
        if fix is None and state is None:
            return None
        return _position.position_json(*self._position_args(state, fix, n_leds))


def pose_filter_class():
    """The class of a device's pose filter (`ServerPoseFilter`)."""
    return ServerPoseFilter
