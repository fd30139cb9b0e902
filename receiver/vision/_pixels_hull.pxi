# Convex hulls of a blob's row extremes and their stats (centroid, area with the half-pixel rim).
# (included by receiver/vision/_pixels.pyx: its imports and byte scans)

cdef extern from *:
    """
    #include <math.h>

    /* z component of (a - o) x (b - o) for integer points: exact in 64 bits */
    static inline int64_t occ_cross(int32_t ox, int32_t oy, int32_t ax, int32_t ay, int32_t bx, int32_t by) {
        return (int64_t)(ax - ox) * (by - oy) - (int64_t)(ay - oy) * (bx - ox);
    }

    /* The convex hull of a blob's row extremes: rows y[j] ascending (j < m, m >= 1), their
       leftmost and rightmost lit columns lx[j] <= rx[j]. Andrew's monotone chain on the points
       in (y, x) order, which is the rows' order (no sort): both chains drop repeated and
       collinear points. The vertices go to hx, hy in cv2.convexHull's orientation (positive
       signed area x dy - y dx), starting at the vertex of largest x, then largest y, where
       cv2.convexHull starts unless its index order shifts it (small hulls); returns their count.
       Work space: px, py (2 m), st (4 m + 1). */
    static int occ_row_hull(const int32_t *lx, const int32_t *rx, const int32_t *y, int m,
                            int32_t *px, int32_t *py, int *st, double *hx, double *hy) {
        int n = 0, k = 0, i, t, best = 0;
        for (i = 0; i < m; i++) {
            px[n] = lx[i]; py[n] = y[i]; n++;
            if (rx[i] != lx[i]) { px[n] = rx[i]; py[n] = y[i]; n++; }
        }
        if (n == 1) {
            hx[0] = px[0]; hy[0] = py[0];
            return 1;
        }
        /* first chain forwards, then the second backwards; st holds point indices */
        for (i = 0; i < n; i++) {
            while (k >= 2 && occ_cross(px[st[k - 2]], py[st[k - 2]], px[st[k - 1]], py[st[k - 1]],
                                       px[i], py[i]) <= 0) k--;
            st[k++] = i;
        }
        for (i = n - 2, t = k + 1; i >= 0; i--) {
            while (k >= t && occ_cross(px[st[k - 2]], py[st[k - 2]], px[st[k - 1]], py[st[k - 1]],
                                       px[i], py[i]) <= 0) k--;
            st[k++] = i;
        }
        k--;  /* the last point is the first again */
        for (i = 1; i < k; i++)
            if (px[st[i]] > px[st[best]] || (px[st[i]] == px[st[best]] && py[st[i]] > py[st[best]]))
                best = i;
        for (i = 0; i < k; i++) {
            int j = st[(best + i) % k];
            hx[i] = px[j];
            hy[i] = py[j];
        }
        return k;
    }

    /* `detect._hull_stats_points` of one polygon (x[i], y[i]), i < k, k >= 1: centroid (cx, cy)
       (Green's theorem) and area plus the half-pixel rim, perimeter / 2 + pi / 4 */
    static void occ_hull_stats(const double *x, const double *y, Py_ssize_t k,
                               double *cx, double *cy, double *area) {
        double a2 = 0.0, sx = 0.0, sy = 0.0, perim = 0.0, mx = 0.0, my = 0.0;
        Py_ssize_t i;
        for (i = 0; i < k; i++) {
            Py_ssize_t j = i + 1 < k ? i + 1 : 0;
            double c = x[i] * y[j] - x[j] * y[i];
            a2 += c;
            sx += (x[i] + x[j]) * c;
            sy += (y[i] + y[j]) * c;
            perim += hypot(x[j] - x[i], y[j] - y[i]);
            mx += x[i];
            my += y[i];
        }
        double m00 = 0.5 * fabs(a2);
        if (m00 <= 1e-6) {
            *cx = mx / (double)k;
            *cy = my / (double)k;
        } else {
            *cx = sx / (3.0 * a2);
            *cy = sy / (3.0 * a2);
        }
        *area = (m00 + 0.5 * perim) + 0.78539816339744830962;
    }
    """
    int occ_row_hull(const int32_t *lx, const int32_t *rx, const int32_t *y, int m, int32_t *px, int32_t *py,
                     int *st, double *hx, double *hy) nogil
    void occ_hull_stats(const double *x, const double *y, Py_ssize_t k, double *cx, double *cy,
                        double *area) nogil
