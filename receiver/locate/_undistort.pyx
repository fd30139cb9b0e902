# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False
"""Compiled undistortion of image points (`receiver.locate.ranging.undistort_points`): OpenCV's
`undistortPoints` algorithm written out, bit for bit its result (tests/locate/test_ranging.py), without
its per-call set-up (a frame undistorts ~1000 outline edge points)."""


def undistort(const double[:, ::1] pts, const double[:, ::1] K, const double[::1] dist, double[:, ::1] out):
    """cv2.undistortPoints(pts, K, dist) (no R, no P): distorted pixels (N, 2) -> normalized
    undistorted image coordinates in `out` (N, 2), by OpenCV's fixed-point iteration (its default
    5 iterations, the rational / thin-prism terms zero for 4, 5 or 8 coefficients given)."""
    cdef int n = pts.shape[0], i, j, nd = dist.shape[0]
    cdef double k[12]
    cdef double fx = K[0, 0], fy = K[1, 1], cx = K[0, 2], cy = K[1, 2]
    cdef double ifx = 1.0 / fx, ify = 1.0 / fy
    cdef double x, y, x0, y0, u, v, r2, icdist, deltaX, deltaY
    cdef bint rational, prism, tangential
    if out.shape[0] != n or pts.shape[1] != 2 or out.shape[1] != 2 or nd > 12:
        raise ValueError("bad undistort arrays")
    for j in range(12):
        k[j] = dist[j] if j < nd else 0.0
    # Terms whose coefficients are all zero are left out: with finite values they add exact
    # zeros (+0: the iteration never starts from -0, as x0 = (u - cx) / fx), so the result is
    # bit for bit the full formula's; a point whose r^2 is not finite takes the full formula.
    rational = k[5] != 0.0 or k[6] != 0.0 or k[7] != 0.0
    prism = k[8] != 0.0 or k[9] != 0.0 or k[10] != 0.0 or k[11] != 0.0
    tangential = k[2] != 0.0 or k[3] != 0.0
    with nogil:
        for i in range(n):
            u = pts[i, 0]
            v = pts[i, 1]
            x = (u - cx) * ifx
            y = (v - cy) * ify
            x0 = x
            y0 = y
            for j in range(5):
                r2 = x * x + y * y
                if rational or prism or not (r2 <= 1.7e308):
                    icdist = (1 + ((k[7] * r2 + k[6]) * r2 + k[5]) * r2) / (1 + ((k[4] * r2 + k[1]) * r2 + k[0]) * r2)
                    if icdist < 0:
                        x = (u - cx) * ifx
                        y = (v - cy) * ify
                        break
                    deltaX = 2 * k[2] * x * y + k[3] * (r2 + 2 * x * x) + k[8] * r2 + k[9] * r2 * r2
                    deltaY = k[2] * (r2 + 2 * y * y) + 2 * k[3] * x * y + k[10] * r2 + k[11] * r2 * r2
                    x = (x0 - deltaX) * icdist
                    y = (y0 - deltaY) * icdist
                    continue
                icdist = 1 / (1 + ((k[4] * r2 + k[1]) * r2 + k[0]) * r2)
                if icdist < 0:
                    x = (u - cx) * ifx
                    y = (v - cy) * ify
                    break
                if tangential:
                    deltaX = 2 * k[2] * x * y + k[3] * (r2 + 2 * x * x)
                    deltaY = k[2] * (r2 + 2 * y * y) + 2 * k[3] * x * y
                    x = (x0 - deltaX) * icdist
                    y = (y0 - deltaY) * icdist
                else:
                    x = x0 * icdist
                    y = y0 * icdist
            out[i, 0] = x
            out[i, 1] = y
