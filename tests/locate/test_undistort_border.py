"""Undistortion near the image border of a strongly distorted lens (`ranging.Undistorter`): every
pixel of the image undistorts to a point that reprojects onto it (cv2.projectPoints, the full
k1 k2 p1 p2 k3 model), where OpenCV's default 5 iterations alone miss by pixels."""

import cv2
import numpy as np

from receiver.io.camera import CameraModel
from receiver.locate.ranging import UNDISTORT_TOL_PX, Undistorter

K = np.array([[1100.0, 0, 639.5], [0, 1100.0, 359.5], [0, 0, 1]])


def _grid():
    xs, ys = np.meshgrid(np.linspace(0, 1279, 41), np.linspace(0, 719, 23))
    return np.column_stack([xs.ravel(), ys.ravel()])


def _reprojection_px(cam, und, pts):
    X = np.column_stack([und, np.ones(len(und))])
    back = cv2.projectPoints(X, np.zeros(3), np.zeros(3), cam.K, cam.dist)[0].reshape(-1, 2)
    return np.hypot(*(back - pts).T)


def test_strong_barrel_lens_undistorts_to_the_border():
    cam = CameraModel(1280, 720, K, np.array([-0.30, 0.0, 0.002, -0.002, 0.0]), fps=30.0)
    pts = _grid()
    default = cv2.undistortPoints(pts.reshape(-1, 1, 2), cam.K, cam.dist).reshape(-1, 2)
    assert _reprojection_px(cam, default, pts).max() > 1.0          # 5 iterations: pixels off
    u = Undistorter(cam)
    assert u.needs_check
    assert _reprojection_px(cam, u(pts), pts).max() <= UNDISTORT_TOL_PX * 1.01


def test_mild_lens_keeps_the_plain_path():
    cam = CameraModel(1280, 720, K, np.array([-0.04, 0.01, 0.0, 0.0, 0.0]), fps=30.0)
    u = Undistorter(cam)
    assert not u.needs_check
    pts = _grid()
    assert _reprojection_px(cam, u(pts), pts).max() < 1e-4
