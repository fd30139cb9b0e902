"""Map-aided association for the vehicle locator (receiver.locate.vehicle): undecoded pairs on
mapped street-light heads projected from the road filter's prediction join the host's pose
solve, never reported as IDs. `MapAssociation` is the locator's part that does it."""

from __future__ import annotations

import math

import cv2
import numpy as np

from receiver.locate.vehicle_host import PITCH_SIGMA_DEG, YAW_SHAKE_SIGMA_DEG
from receiver.locate.vehicle_ranging import CENTROID_SIGMA_PX


# Model constants of the association, unit and why.
ASSOC_MAX_STD_M = 1.0           # m, undecoded pairs are matched to mapped heads only while the filter's 2D std is at most this
ASSOC_GATE_CHI2 = 9.21          # ... Mahalanobis^2 gate of a pair's midpoint to a projected head (chi-square 2 dof, 99 %)
ASSOC_MAX_AGE = 1               # frames, ... both emitters' own blobs seen within this
ASSOC_SEP_TOL = 0.3             # ... and the separation within this fraction of the head's predicted one


class MapAssociation:
    """The locator's map-aided association (a mixin of `VehicleLocator`)."""

    def _associate(self, t_s: float, pairs, R_prior) -> dict:
        """Map-aided association {pair index: mapped street-light ID} of UNDECODED pairs, while
        the road filter is sure (predicted 2D std <= `ASSOC_MAX_STD_M`): every mapped head not
        decoded in this frame is projected from the predicted camera (the filter's x, y; the
        last solved height and orientation turned to the predicted heading) with its 2x2
        covariance in normalized image units (the position's through the projection's Jacobian,
        plus the camera's yaw and pitch sigmas and the centroids'); a pair both of whose
        emitters were measured apart (`both_visible`) is matched to the one head whose
        Mahalanobis^2 to its midpoint is within `ASSOC_GATE_CHI2`, when no other head is in
        that gate, no other pair is in the head's, and its separation is within
        `ASSOC_SEP_TOL` of the head's predicted one (f B / distance). Ambiguity: no match."""
        cand = [i for i, p in enumerate(pairs) if p.led_id is None and p.both_visible
                and p.a_seen is not None and p.b_seen is not None
                and max(int(p.a_seen[2]), int(p.b_seen[2])) <= ASSOC_MAX_AGE]
        if not cand or not len(self._sl_heads):
            return {}
        st, P = self.kf.predict_at(t_s)
        Pxy = P[:2, :2]
        if float(Pxy[0, 0] + Pxy[1, 1]) > ASSOC_MAX_STD_M ** 2:
            return {}
        decoded = {p.led_id for p in pairs if p.led_id is not None}
        ids, H, Bl = self._em_heads
        keep = [i not in decoded for i in ids]
        if not all(keep):
            ids, H, Bl = [i for i, k in zip(ids, keep) if k], H[keep], Bl[keep]
        if not ids:
            return {}
        R, C = self._prior_camera(st, R_prior)
        V = H - np.array(C)
        X = V @ R.T
        ok = X[:, 2] > 1.0
        if not np.any(ok):
            return {}
        X, V, Bl, ids = X[ok], V[ok], Bl[ok], [i for i, o in zip(ids, ok) if o]
        z = X[:, 2]
        u = X[:, :2] / z[:, None]
        # d(u, v) / d(Cx, Cy): X = R (H - C) -> dX/dC = -R[:, :2].
        dX = -R[:, :2]                                       # (3, 2)
        J = (dX[None, :2, :] - u[:, :, None] * dX[None, 2:3, :]) / z[:, None, None]     # (n, 2, 2)
        cov = J @ Pxy @ np.transpose(J, (0, 2, 1))
        ang = math.radians(YAW_SHAKE_SIGMA_DEG) ** 2 + math.radians(PITCH_SIGMA_DEG) ** 2
        csig = (CENTROID_SIGMA_PX / self.focal) ** 2
        cov = cov + np.eye(2) * (ang + csig)
        inv = np.linalg.inv(cov)
        sep_pred = self.focal * Bl / np.sqrt(np.sum(V * V, axis=1))
        und = self._undistorted_mids(pairs, cand)
        D = und[:, None, :] - u[None, :, :]                  # (pairs, heads, 2)
        m2 = np.einsum("phi,hij,phj->ph", D, inv, D)
        inside = m2 <= ASSOC_GATE_CHI2
        out = {}
        for a, i in enumerate(cand):
            hs = np.flatnonzero(inside[a])
            if len(hs) != 1 or np.count_nonzero(inside[:, hs[0]]) != 1:
                continue
            h = hs[0]
            sep = pairs[i].separation_px
            if not (sep > 0 and abs(sep / sep_pred[h] - 1.0) <= ASSOC_SEP_TOL):
                continue
            out[i] = ids[h]
        return out

    def _undistorted_mids(self, pairs, cand) -> np.ndarray:
        """(len(cand), 2) normalized, undistorted image midpoints of the candidate pairs."""
        mids = [(0.5 * (pairs[i].a_px[0] + pairs[i].b_px[0]), 0.5 * (pairs[i].a_px[1] + pairs[i].b_px[1]))
                for i in cand]
        return cv2.undistortPoints(np.array(mids, float).reshape(-1, 1, 2), self.camera.K,
                                   self.camera.dist).reshape(-1, 2)

    def _prior_camera(self, st, R_prior):
        """The predicted camera of `_associate`: R_prior turned about z by the heading change
        since the filter's last update, at the filter's predicted x, y and the last height."""
        dpsi = float(st[2]) - float(self.kf.s[2])          # heading change since the last update
        c, sn = math.cos(dpsi), math.sin(dpsi)
        R = R_prior @ np.array([[c, sn, 0.0], [-sn, c, 0.0], [0.0, 0.0, 1.0]])    # turned by dpsi about z
        return R, (float(st[0]), float(st[1]), self.z_last)
