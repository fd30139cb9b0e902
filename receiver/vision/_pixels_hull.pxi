# Convex hulls of integer points and their stats (centroid, area with the half-pixel rim).
# (included by receiver/vision/_pixels.pyx: its imports and byte scans)

# ------------------------------------------------------------------ detection: hulls of isolated blobs

cdef extern from *:
    """
    #include <math.h>
    #include <stdint.h>

    /* numpy's pairwise summation (np.add.reduce of float64, PW_BLOCKSIZE 128), a[0..n) */
    static double occ_pw_sum(const double *a, Py_ssize_t n) {
        Py_ssize_t i;
        if (n < 8) {
            double res = -0.0;
            for (i = 0; i < n; i++) res += a[i];
            return res;
        }
        if (n <= 128) {
            double r[8], res;
            for (i = 0; i < 8; i++) r[i] = a[i];
            for (i = 8; i < n - (n % 8); i += 8) {
                r[0] += a[i + 0]; r[1] += a[i + 1]; r[2] += a[i + 2]; r[3] += a[i + 3];
                r[4] += a[i + 4]; r[5] += a[i + 5]; r[6] += a[i + 6]; r[7] += a[i + 7];
            }
            res = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]));
            for (; i < n; i++) res += a[i];
            return res;
        }
        {
            Py_ssize_t n2 = n / 2;
            n2 -= n2 % 8;
            return occ_pw_sum(a, n2) + occ_pw_sum(a + n2, n - n2);
        }
    }

    /* one segment of np.add.reduceat (n >= 1): its first element plus the pairwise sum of the rest */
    static inline double occ_seg_sum(const double *a, Py_ssize_t n) {
        double s = a[0];
        if (n > 1) s += occ_pw_sum(a + 1, n - 1);
        return s;
    }

    /* ascending sort of distinct keys (quicksort, median of three; insertion sort below 17) */
    static void occ_sort_u64(uint64_t *a, Py_ssize_t n) {
        while (n > 16) {
            uint64_t x = a[0], y = a[n / 2], z = a[n - 1], p, t;
            Py_ssize_t i = -1, j = n;
            p = x < y ? (y < z ? y : (x < z ? z : x)) : (x < z ? x : (y < z ? z : y));
            for (;;) {
                do i++; while (a[i] < p);
                do j--; while (a[j] > p);
                if (i >= j) break;
                t = a[i]; a[i] = a[j]; a[j] = t;
            }
            /* [0, j] and [j + 1, n): recurse into the smaller */
            if (j + 1 < n - j - 1) {
                occ_sort_u64(a, j + 1);
                a += j + 1;
                n -= j + 1;
            } else {
                occ_sort_u64(a + j + 1, n - j - 1);
                n = j + 1;
            }
        }
        for (Py_ssize_t i = 1; i < n; i++) {
            uint64_t v = a[i];
            Py_ssize_t j = i;
            while (j > 0 && a[j - 1] > v) { a[j] = a[j - 1]; j--; }
            a[j] = v;
        }
    }

    #define OCC_SIGN(v) (((v) > 0) - ((v) < 0))

    /* OpenCV's Sklansky_ (imgproc/src/convhull.cpp) on the sorted points (px[k], py[k]) */
    static int occ_sklansky(const int32_t *px, const int32_t *py, int start, int end, int *stack,
                            int nsign, int sign2) {
        int incr = end > start ? 1 : -1;
        int pprev = start, pcur = pprev + incr, pnext = pcur + incr;
        int stacksize = 3;
        if (start == end || (px[start] == px[end] && py[start] == py[end])) {
            stack[0] = start;
            return 1;
        }
        stack[0] = pprev;
        stack[1] = pcur;
        stack[2] = pnext;
        end += incr;
        while (pnext != end) {
            int cury = py[pcur], nexty = py[pnext], by = nexty - cury;
            if (OCC_SIGN(by) != nsign) {
                int ax = px[pcur] - px[pprev], ay = cury - py[pprev];
                int bx = px[pnext] - px[pcur];
                int64_t convexity = (int64_t)ay * bx - (int64_t)ax * by;
                if (OCC_SIGN(convexity) == sign2 && (ax != 0 || ay != 0)) {
                    pprev = pcur;
                    pcur = pnext;
                    pnext += incr;
                    stack[stacksize] = pnext;
                    stacksize++;
                } else if (pprev == start) {
                    pcur = pnext;
                    stack[1] = pcur;
                    pnext += incr;
                    stack[2] = pnext;
                } else {
                    stack[stacksize - 2] = pnext;
                    pcur = pprev;
                    pprev = stack[stacksize - 4];
                    stacksize--;
                }
            } else {
                pnext += incr;
                stack[stacksize - 1] = pnext;
            }
        }
        return --stacksize;
    }

    /* cv2.convexHull(points, clockwise=False) of the integer points (x[i], y[i]), i < total
       (0 <= x, y, total < 2^21): the indices of its vertices, in OpenCV's order, into hull;
       returns their count. Work space: keys (total), ord, px, py (total), stack (2 total + 4).
       keys NULL: ord holds the indices already sorted by (x, y, index).
       A port of OpenCV 5.0's convexHull for integer points: points sorted by (x, y, index)
       (its comparator's order, a total one: any sort gives its order), the upper and lower
       chains by Sklansky's scan (equal points are not skipped), and the cyclic shift that makes
       the indices ascending or descending where it can. tests/engine/test_detect_kernels.py checks
       it against cv2.convexHull on random point sets with many equal points. */
    static int occ_convex_hull(const int32_t *x, const int32_t *y, int total, uint64_t *keys,
                               int *ord, int32_t *px, int32_t *py, int *stack, int *hull) {
        int i, nout = 0, miny_ind = 0, maxy_ind = 0;
        if (keys != NULL) {
            for (i = 0; i < total; i++)
                keys[i] = ((uint64_t)x[i] << 42) | ((uint64_t)y[i] << 21) | (uint64_t)i;
            occ_sort_u64(keys, total);
            for (i = 0; i < total; i++) ord[i] = (int)(keys[i] & 0x1FFFFF);
        }
        for (i = 0; i < total; i++) {
            px[i] = x[ord[i]];
            py[i] = y[ord[i]];
        }
        for (i = 1; i < total; i++) {
            if (py[miny_ind] > py[i]) miny_ind = i;
            if (py[maxy_ind] < py[i]) maxy_ind = i;
        }
        if (px[0] == px[total - 1] && py[0] == py[total - 1]) {
            hull[nout++] = 0;
            return nout;
        }
        {
            /* upper half (clockwise = false: the two stacks swapped) */
            int *tr_stack = stack;
            int tr_count = occ_sklansky(px, py, 0, maxy_ind, tr_stack, -1, 1);
            int *tl_stack = stack + tr_count;
            int tl_count = occ_sklansky(px, py, total - 1, maxy_ind, tl_stack, -1, -1);
            for (i = 0; i < tl_count - 1; i++) hull[nout++] = ord[tl_stack[i]];
            for (i = tr_count - 1; i > 0; i--) hull[nout++] = ord[tr_stack[i]];
            int stop_idx = tr_count > 2 ? tr_stack[1] : tl_count > 2 ? tl_stack[tl_count - 2] : -1;
            /* lower half */
            int *bl_stack = stack;
            int bl_count = occ_sklansky(px, py, 0, miny_ind, bl_stack, 1, -1);
            int *br_stack = stack + bl_count;
            int br_count = occ_sklansky(px, py, total - 1, miny_ind, br_stack, 1, 1);
            if (stop_idx >= 0) {
                int check_idx = bl_count > 2 ? bl_stack[1] :
                                bl_count + br_count > 2 ? br_stack[2 - bl_count] : -1;
                if (check_idx == stop_idx || (check_idx >= 0 && px[check_idx] == px[stop_idx]
                                              && py[check_idx] == py[stop_idx])) {
                    if (bl_count > 2) bl_count = 2;
                    if (br_count > 2) br_count = 2;
                }
            }
            for (i = 0; i < bl_count - 1; i++) hull[nout++] = ord[bl_stack[i]];
            for (i = br_count - 1; i > 0; i--) hull[nout++] = ord[br_stack[i]];
        }
        if (nout >= 3) {
            int min_idx = 0, max_idx = 0, lt = 0;
            for (i = 1; i < nout; i++) {
                int idx = hull[i];
                lt += hull[i - 1] < idx;
                if (lt > 1 && lt <= i - 2) break;
                if (idx < hull[min_idx]) min_idx = i;
                if (idx > hull[max_idx]) max_idx = i;
            }
            int mmdist = abs(max_idx - min_idx);
            if ((mmdist == 1 || mmdist == nout - 1) && (lt <= 1 || lt >= nout - 2)) {
                int ascending = (max_idx + 1) % nout == min_idx;
                int i0 = ascending ? min_idx : max_idx, j = i0;
                if (i0 > 0) {
                    for (i = 0; i < nout; i++) {
                        int curr_idx = stack[i] = hull[j];
                        int next_j = j + 1 < nout ? j + 1 : 0;
                        int next_idx = hull[next_j];
                        if (i < nout - 1 && (ascending != (curr_idx < next_idx))) break;
                        j = next_j;
                    }
                    if (i == nout) memcpy(hull, stack, nout * sizeof(hull[0]));
                }
            }
        }
        return nout;
    }

    /* hypot of small integer differences from a table of hypot's own results (the same bits:
       glibc's hypot takes |x| and |y| first), hypot itself for the rest; the hull's vertices are
       integer pixel centres. occ_hypot_init fills the table once, at the module's import. */
    #define OCC_HYP_N 64
    static double occ_hyp_tab[OCC_HYP_N * OCC_HYP_N];
    static int occ_hyp_ready = 0;
    static void occ_hypot_init(void) {
        for (int a = 0; a < OCC_HYP_N; a++)
            for (int b = 0; b < OCC_HYP_N; b++)
                occ_hyp_tab[a * OCC_HYP_N + b] = hypot((double)a, (double)b);
        occ_hyp_ready = 1;
    }
    static inline double occ_hypot(double dx, double dy) {
        double ax = fabs(dx), ay = fabs(dy);
        if (occ_hyp_ready && ax < (double)OCC_HYP_N && ay < (double)OCC_HYP_N) {
            int ix = (int)ax, iy = (int)ay;
            if ((double)ix == ax && (double)iy == ay)
                return occ_hyp_tab[ix * OCC_HYP_N + iy];
        }
        return hypot(dx, dy);
    }

    /* `detect._hull_stats_points` of one polygon (x[i], y[i]), i < k, k >= 1: centroid (cx, cy)
       and area plus half-pixel rim, with numpy's operations in numpy's order (reduceat sums).
       w: work space of 4 k doubles. */
    static void occ_hull_stats(const double *x, const double *y, Py_ssize_t k, double *w,
                               double *cx, double *cy, double *area) {
        double *cr = w, *sxv = w + k, *syv = w + 2 * k, *pv = w + 3 * k;
        Py_ssize_t i;
        for (i = 0; i < k; i++) {
            Py_ssize_t j = i + 1 < k ? i + 1 : 0;
            double xn = x[j], yn = y[j];
            double c = x[i] * yn - xn * y[i];
            cr[i] = c;
            sxv[i] = (x[i] + xn) * c;
            syv[i] = (y[i] + yn) * c;
            pv[i] = occ_hypot(xn - x[i], yn - y[i]);
        }
        double a2 = occ_seg_sum(cr, k), sx = occ_seg_sum(sxv, k), sy = occ_seg_sum(syv, k);
        double perim = occ_seg_sum(pv, k);
        double m00 = 0.5 * fabs(a2);
        if (m00 <= 1e-6) {
            *cx = occ_seg_sum(x, k) / (double)k;
            *cy = occ_seg_sum(y, k) / (double)k;
        } else {
            *cx = sx / (3.0 * a2);
            *cy = sy / (3.0 * a2);
        }
        *area = (m00 + 0.5 * perim) + 0.78539816339744830962;
    }
    """
    int occ_convex_hull(const int32_t *x, const int32_t *y, int total, uint64_t *keys, int *ord,
                        int32_t *px, int32_t *py, int *stack, int *hull) nogil
    void occ_hull_stats(const double *x, const double *y, Py_ssize_t k, double *w, double *cx,
                        double *cy, double *area) nogil
    double occ_seg_sum(const double *a, Py_ssize_t n) nogil
    void occ_sort_u64(uint64_t *a, Py_ssize_t n) nogil
    void occ_hypot_init() nogil
    double occ_hypot(double dx, double dy) nogil


occ_hypot_init()


def hypot_table_equals_hypot():
    """Whether the hull perimeter's table of hypot(a, b), 0 <= a, b < 64, and its look-up
    (negative, fractional and large differences included) give hypot's own bits (for the
    tests)."""
    cdef int a, b
    cdef double x, y
    for a in range(-70, 71):
        for b in range(-70, 71):
            for x, y in ((a, b), (a + 0.5, b), (a, b - 0.25), (-0.0 * a, b)):
                if occ_hypot(x, y) != hypot(x, y):
                    return False
    return True



def convex_hull(const int32_t[:, ::1] pts):
    """cv2.convexHull of (N, 2) int32 points (0 <= x, y < 2^21, N < 2^21): (K, 2) int32
    vertices in OpenCV's order (`occ_convex_hull`; for the kernel's tests)."""
    cdef int n = pts.shape[0], i, k
    if n == 0:
        return []
    if n >= (1 << 21):
        raise ValueError("too many points")
    for i in range(n):
        if pts[i, 0] < 0 or pts[i, 1] < 0 or pts[i, 0] >= (1 << 21) or pts[i, 1] >= (1 << 21):
            raise ValueError("points outside [0, 2^21)")
    cdef int32_t *x = <int32_t *>malloc(4 * n * sizeof(int32_t))
    cdef uint64_t *keys = <uint64_t *>malloc(n * sizeof(uint64_t))
    cdef int *iw = <int *>malloc((4 * n + 8) * sizeof(int))
    if x == NULL or keys == NULL or iw == NULL:
        free(x); free(keys); free(iw)
        raise MemoryError()
    try:
        for i in range(n):
            x[i] = pts[i, 0]
            x[n + i] = pts[i, 1]
        k = occ_convex_hull(x, x + n, n, keys, iw, x + 2 * n, x + 3 * n, iw + n, iw + 3 * n + 4)
        return [(int(x[iw[3 * n + 4 + i]]), int(x[n + iw[3 * n + 4 + i]])) for i in range(k)]
    finally:
        free(x); free(keys); free(iw)


def hull_stats(const double[:, ::1] poly, const int64_t[::1] starts, double[:, ::1] out):
    """out[i] = (cx, cy, area_px) of polygon i, rows starts[i]:starts[i + 1] of `poly` (x, y)
    (`detect._hull_stats_points`, bit for bit)."""
    cdef Py_ssize_t n = starts.shape[0] - 1, i, j, k, kmax = 0
    for i in range(n):
        if starts[i + 1] - starts[i] > kmax:
            kmax = starts[i + 1] - starts[i]
    cdef double *w = <double *>malloc((7 * kmax + 1) * sizeof(double))
    if w == NULL:
        raise MemoryError()
    try:
        for i in range(n):
            k = starts[i + 1] - starts[i]
            for j in range(k):
                w[5 * kmax + j] = poly[starts[i] + j, 0]
                w[6 * kmax + j] = poly[starts[i] + j, 1]
            occ_hull_stats(w + 5 * kmax, w + 6 * kmax, k, w, &out[i, 0], &out[i, 1], &out[i, 2])
    finally:
        free(w)
