"""Locating stage: ranges (`ranging`), least squares (`lsq`), multilateration (`multilat`),
camera pose (`pose`), pose + Kalman per device (`posefilter`, `kalman`), the indoor positioner
(`indoor`).
"""
