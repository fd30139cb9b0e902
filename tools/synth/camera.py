"""Camera geometry for the synthetic camera: pose convention, projection, row timing.

World frame: x, y on the floor, z up, metres (vehicle scenes: x along the road, y to the left).

Camera pose = position (x, y, z) in metres plus (yaw, pitch, roll) in degrees:

* With yaw = pitch = roll = 0 the camera looks horizontally along world +x; the image's
  right (OpenCV camera +x) is world -y and the image's down (camera +y) is world -z.
* The camera-to-world rotation is ``R_wc = Rz(yaw) @ Ry(-pitch) @ Rx(roll) @ B`` where ``B``
  maps OpenCV camera axes (x right, y down, z optical axis) to a body frame (x forward,
  y left, z up), and Rz, Ry, Rx are right-handed rotations about the world/body axes.
  So: yaw turns the optical axis to the left (counter-clockwise seen from above, +x towards +y);
  pitch > 0 raises the optical axis (pitch = +90 looks straight up at the ceiling, and then
  the image's down direction is world +x rotated by yaw, image right is world -y rotated
  by yaw); roll > 0 turns the camera clockwise as seen from behind it, about its own optical
  axis... precisely: a right-handed rotation about the body forward axis (left side up).
* A world point P maps to camera coordinates ``p_c = R_wc.T @ (P - C)``.

Projection is the OpenCV pinhole model with the 5-coefficient distortion (k1 k2 p1 p2 k3),
identical to ``cv2.projectPoints`` (tests check this) but vectorised in numpy without the
Jacobians. Pixel centres are at integer coordinates (OpenCV convention), so pixel (u, v)
covers [u-0.5, u+0.5] x [v-0.5, v+0.5].

Rolling shutter: row r of frame k is exposed over ``[t_k + r*t_row, t_k + r*t_row + t_exp]``
(PROTOCOL.md section 2); ``row_readout_us = 0`` is a global shutter.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from receiver.io.camera import CameraModel

# OpenCV camera axes expressed in the body frame (x forward, y left, z up): columns are
# camera x (right) = -y_body, camera y (down) = -z_body, camera z (optical axis) = +x_body.
CAM_TO_BODY = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


@dataclass(frozen=True)
class Pose:
    """Camera pose in the world frame: metres and degrees (convention in the module docstring)."""

    x: float
    y: float
    z: float
    yaw: float = 0.0
    pitch: float = 0.0
    roll: float = 0.0

    @property
    def position(self) -> np.ndarray:
        return np.array([self.x, self.y, self.z], dtype=np.float64)

    def as_dict(self, ndigits: int = 6) -> dict:
        return {k: round(float(getattr(self, k)), ndigits) for k in ("x", "y", "z", "yaw", "pitch", "roll")}


def _rot_x(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0, 0], [0, c, -s], [0, s, c]])


def _rot_y(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1.0, 0], [-s, 0, c]])


def _rot_z(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def rotation_cam_to_world(yaw_deg: float, pitch_deg: float, roll_deg: float) -> np.ndarray:
    """3x3 rotation R_wc whose columns are the OpenCV camera axes in world coordinates."""
    r = math.radians
    return _rot_z(r(yaw_deg)) @ _rot_y(-r(pitch_deg)) @ _rot_x(r(roll_deg)) @ CAM_TO_BODY


def world_to_camera(points_w: np.ndarray, pose: Pose) -> np.ndarray:
    """(N, 3) world points -> (N, 3) OpenCV camera coordinates (z = depth along the axis)."""
    R = rotation_cam_to_world(pose.yaw, pose.pitch, pose.roll)
    return (np.asarray(points_w, dtype=np.float64) - pose.position) @ R


def distort_normalized(xn: np.ndarray, yn: np.ndarray, dist: np.ndarray):
    """OpenCV radial-tangential distortion of normalised coordinates (k1 k2 p1 p2 k3)."""
    k1, k2, p1, p2, k3 = (float(v) for v in np.asarray(dist, dtype=np.float64).ravel()[:5])
    r2 = xn * xn + yn * yn
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = xn * radial + 2.0 * p1 * xn * yn + p2 * (r2 + 2.0 * xn * xn)
    yd = yn * radial + p1 * (r2 + 2.0 * yn * yn) + 2.0 * p2 * xn * yn
    return xd, yd


def project_camera_points(pc: np.ndarray, cam: CameraModel) -> np.ndarray:
    """(N, 3) camera-frame points (z > 0) -> (N, 2) distorted pixel coordinates (u, v)."""
    z = pc[:, 2]
    xd, yd = distort_normalized(pc[:, 0] / z, pc[:, 1] / z, cam.dist)
    K = cam.K
    u = K[0, 0] * xd + K[0, 1] * yd + K[0, 2]
    v = K[1, 1] * yd + K[1, 2]
    return np.stack([u, v], axis=1)


def max_normalized_radius(cam: CameraModel, margin: float = 1.25) -> float:
    """Radius in undistorted normalised coordinates beyond which points are not projected.

    The polynomial distortion model folds back far outside the field of view, so points
    whose undistorted radius exceeds `margin` times the radius of the image corners are
    treated as outside the image (never drawn).
    """
    corners = np.array([[0, 0], [cam.width - 1, 0], [0, cam.height - 1], [cam.width - 1, cam.height - 1]],
                       dtype=np.float64)
    xn = (corners[:, 0] - cam.cx) / cam.fx
    yn = (corners[:, 1] - cam.cy) / cam.fy
    return margin * float(np.sqrt(xn * xn + yn * yn).max())


def row_start_times_s(t_frame_s: float, n_rows: int, row_readout_us: float) -> np.ndarray:
    """Exposure start of each image row: ``t_k + r * t_row`` (seconds)."""
    return t_frame_s + np.arange(n_rows, dtype=np.float64) * (row_readout_us * 1e-6)


def make_camera(width: int = 1280, height: int = 720, focal_px: float = 1000.0,
                dist=(0.0, 0.0, 0.0, 0.0, 0.0), pixel_size_um: float = 3.0,
                row_readout_us: float = 15.0, exposure_us: float = 20.0, fps: float = 30.0) -> CameraModel:
    """A CameraModel with square pixels, principal point at the image centre.

    `focal_length_mm` is derived as ``focal_px * pixel_size_um / 1000`` so that thesis
    eq. 18's f/rho equals fx exactly.
    """
    K = np.array([[focal_px, 0.0, (width - 1) / 2.0], [0.0, focal_px, (height - 1) / 2.0], [0.0, 0.0, 1.0]])
    return CameraModel(width=int(width), height=int(height), K=K, dist=np.asarray(dist, dtype=np.float64),
                       pixel_size_um=float(pixel_size_um), focal_length_mm=float(focal_px * pixel_size_um / 1000.0),
                       row_readout_us=float(row_readout_us), exposure_us=float(exposure_us), fps=float(fps))
