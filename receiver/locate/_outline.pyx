# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False
"""Outline-pose solve (`receiver.locate.outline_pose.solve_outline_pose`), its one
implementation: the edge assignment, the whitened residuals, the IRLS normal equations
(per-edge moments for squares / rects, analytic Jacobians for circles, centroids and priors) and
the Levenberg-Marquardt rounds of one frame in one call (tests/locate/test_outline_solve.py:
known poses, the covariance against np.linalg.pinv).

Parameters p = (Rodrigues vector of R_cw, C); normalized image coordinates. Input: every target's
edge points in turn (`outline_pose.OutlineFrame`), each target a square / rect (4 straight edges)
or a circle. Residuals: one per edge point (in the frame's order; a square / rect point near a
corner unused, 0), the centroids (u, v) of the targets that have one, the tilt prior (3), the
position prior (3): grouped squares / rects first, then circles."""

from libc.math cimport sqrt, cos, sin, fabs
from receiver.locate._rodrigues cimport rodrigues, cam_point
from receiver.locate._solve6 cimport lm_damping, lm_step
from receiver.locate._loss cimport loss_rho, loss_w
from libc.stdlib cimport malloc, free
from libc.string cimport memset



cdef struct Prob:
    int N          # edge points
    int M          # ... of squares / rects
    int T          # targets
    int K          # centroids
    const double* P        # (N, 2)
    const double* w        # (N,) 1 / sigma
    const int* tix         # (N,) target of each point
    const int* circ        # (T,) 1: circle, 0: square / rect
    const double* xyz      # (T, 3)
    const double* half     # (T, 2)
    double* corners        # (4T, 3) (squares / rects)
    double* AxB            # (4T, 3) A x B of each edge's corners A, B
    double* D              # (4T, 3) A - B
    int* lab               # (N,) edge 0..3 of each square / rect point, -1: unused
    double* L              # (K, 3) centres of the targets with a centroid
    double* uv             # (K, 2) their centroids
    double sigc
    int has_up
    double up[3]
    double up_sig
    int has_prior
    double Cp[3]
    double W[9]
    int loss
    double fs
    int n_res              # residuals (incl. the position prior's)
    int n_buf              # doubles of a residual buffer: n_res residuals, then 4 per point of the
                           # circles' per-point terms at the same pose (`evaluate` -> `normal`)
    double* nh             # (4T, 3) work: the edges' image lines
    double* rho            # (4T,)
    double* m              # (4T, 3)
    double* S              # (4T, 9) work: per-edge moment sums
    double* c6             # (T, 6) work: circles' image conics
    double* QRt            # (T, 9)
    double* dc6            # (T, 36) work: d c6 / d p of each circle
    int* flat              # (T,)
    int* order             # (N,) used square / rect points grouped by edge (stable), then circle points
    int* estart            # (4T + 1,) where each edge's run starts in `order`
    int n_edge_pts         # used square / rect points (the runs' total)


cdef inline double hypot(double a, double b) noexcept nogil:
    """sqrt(a^2 + b^2) without libm's hypot (~45 instructions a call, 5000 calls a frame): its
    overflow / underflow guards are not needed for normalized image coordinates, and the two
    differ by at most an ulp."""
    return sqrt(a * a + b * b)


cdef inline void project(const double* R, const double* C, const double* X, double* q) noexcept nogil:
    """Normalized image point of world point X (depth clamped at 1e-6, as `_project`)."""
    cdef double y[3]
    cdef double x[3]
    cdef double z
    cam_point(X, C, R, y, x)
    z = x[2] if x[2] > 1e-6 else 1e-6
    q[0] = x[0] / z
    q[1] = x[1] / z


cdef int assign(Prob* pr, const double* p, int keep_minor, int first, double guard2,
                int minor_switches, double minor_fraction) noexcept nogil:
    """`_Problem.assign`: label every square / rect point with its nearest edge at pose p (-1
    within the corner guard; a point beyond a corner goes to the first of its two edges); returns
    1 when the labels changed."""
    cdef double R[9]
    cdef double dR[27]
    cdef int t, i, j, n, lab, old, switched = 0, changed = 0
    cdef double* tab
    cdef double* q
    cdef double* ab
    cdef double* il
    cdef double d2[4]
    cdef double c2[4]
    cdef double rx[4]
    cdef double ry[4]
    cdef double s, ex, ey, m01, m23, dc, thr
    cdef int* new
    if pr.M == 0:
        return first
    rodrigues(p, R, dR)
    new = <int*> malloc(pr.N * sizeof(int))
    tab = <double*> malloc(pr.T * 20 * sizeof(double))
    if new == NULL or tab == NULL:
        free(new)
        free(tab)
        return 0
    # Per target: projected corners q (4, 2), edge vectors ab (4, 2), 1 / |ab|^2 (4,).
    for t in range(pr.T):
        if pr.circ[t]:
            continue
        q = tab + 20 * t
        ab = q + 8
        il = q + 16
        for j in range(4):
            project(R, p + 3, pr.corners + (4 * t + j) * 3, q + 2 * j)
        for j in range(4):
            n = (j + 1) % 4
            ab[2 * j] = q[2 * n] - q[2 * j]
            ab[2 * j + 1] = q[2 * n + 1] - q[2 * j + 1]
            s = ab[2 * j] * ab[2 * j] + ab[2 * j + 1] * ab[2 * j + 1]
            il[j] = 1.0 / (s if s > 1e-18 else 1e-18)
    for i in range(pr.N):
        t = pr.tix[i]
        if pr.circ[t]:
            new[i] = -1
            continue
        q = tab + 20 * t
        ab = q + 8
        il = q + 16
        for j in range(4):
            rx[j] = pr.P[2 * i] - q[2 * j]
            ry[j] = pr.P[2 * i + 1] - q[2 * j + 1]
            c2[j] = rx[j] * rx[j] + ry[j] * ry[j]
        for j in range(4):
            s = (rx[j] * ab[2 * j] + ry[j] * ab[2 * j + 1]) * il[j]
            if s <= 0.0:
                d2[j] = c2[j]                 # nearest: the edge's start corner
            elif s >= 1.0:
                d2[j] = c2[(j + 1) & 3]       # ... its end corner
            else:
                ex = rx[j] - s * ab[2 * j]
                ey = ry[j] - s * ab[2 * j + 1]
                d2[j] = ex * ex + ey * ey
        m01 = d2[0] if d2[0] <= d2[1] else d2[1]
        m23 = d2[2] if d2[2] <= d2[3] else d2[3]
        if m23 < m01:
            lab = 3 if d2[3] < d2[2] else 2
        else:
            lab = 1 if d2[1] < d2[0] else 0
        dc = c2[0]
        for j in range(1, 4):
            if c2[j] < dc:
                dc = c2[j]
        if dc < guard2:
            lab = -1
        new[i] = lab
    free(tab)
    if keep_minor and not first:
        for i in range(pr.N):
            old = pr.lab[i]
            if new[i] != old and new[i] >= 0 and old >= 0:
                switched += 1
        thr = minor_fraction * pr.M
        if switched <= (minor_switches if minor_switches > thr else thr):
            free(new)
            return 0
    for i in range(pr.N):
        if first or new[i] != pr.lab[i]:
            changed = 1
        pr.lab[i] = new[i]
    free(new)
    return changed


cdef void group(Prob* pr) noexcept nogil:
    """`order` / `estart`: the used square / rect points in runs per edge (each run in point
    order, as `_Problem._group`'s stable sort), then every circle point."""
    cdef int i, e, E = 4 * pr.T, pos
    for e in range(E + 1):
        pr.estart[e] = 0
    for i in range(pr.N):
        if not pr.circ[pr.tix[i]] and pr.lab[i] >= 0:
            pr.estart[4 * pr.tix[i] + pr.lab[i] + 1] += 1
    for e in range(E):
        pr.estart[e + 1] += pr.estart[e]
    pr.n_edge_pts = pr.estart[E]
    pos = pr.n_edge_pts
    for i in range(pr.N):
        if pr.circ[pr.tix[i]]:
            pr.order[pos] = i
            pos += 1
        elif pr.lab[i] >= 0:
            e = 4 * pr.tix[i] + pr.lab[i]
            pr.order[pr.estart[e]] = i
            pr.estart[e] += 1
    for e in range(E - 1, 0, -1):
        pr.estart[e] = pr.estart[e - 1]
    if E:
        pr.estart[0] = 0


cdef void edge_lines(Prob* pr, const double* R, const double* C) noexcept nogil:
    """Every square / rect edge's plane normal m = A x B + C x (A - B), camera-frame n = R m, and
    image line nh = n / |(n0, n1)|."""
    cdef int e
    cdef double m0, m1, m2, n0, n1, n2, rho
    cdef const double* a
    cdef const double* d
    for e in range(4 * pr.T):
        if pr.circ[e // 4]:
            continue
        a = pr.AxB + 3 * e
        d = pr.D + 3 * e
        m0 = a[0] + (C[1] * d[2] - C[2] * d[1])
        m1 = a[1] + (C[2] * d[0] - C[0] * d[2])
        m2 = a[2] + (C[0] * d[1] - C[1] * d[0])
        pr.m[3 * e] = m0
        pr.m[3 * e + 1] = m1
        pr.m[3 * e + 2] = m2
        n0 = m0 * R[0] + m1 * R[1] + m2 * R[2]
        n1 = m0 * R[3] + m1 * R[4] + m2 * R[5]
        n2 = m0 * R[6] + m1 * R[7] + m2 * R[8]
        rho = hypot(n0, n1)
        if not (rho > 1e-15):
            rho = 1e-15 if rho == rho else rho
        pr.rho[e] = rho
        pr.nh[3 * e] = n0 / rho
        pr.nh[3 * e + 1] = n1 / rho
        pr.nh[3 * e + 2] = n2 / rho


cdef void circle_conics(Prob* pr, const double* R, const double* C) noexcept nogil:
    """Each circle's image conic Ci = R Q R^T (`_Problem._circles`): its six distinct entries,
    Q R^T and whether it is seen edge-on."""
    cdef int t, a, b
    cdef double d0, d1, cz, al, be, hr
    cdef double Q[9]
    cdef double* qr
    cdef double Ci[9]
    for t in range(pr.T):
        if not pr.circ[t]:
            continue
        d0 = pr.xyz[3 * t] - C[0]
        d1 = pr.xyz[3 * t + 1] - C[1]
        cz = pr.xyz[3 * t + 2] - C[2]
        pr.flat[t] = 1 if cz == 0.0 else 0
        if cz == 0.0:
            cz = 1.0
        al = d0 / cz
        be = d1 / cz
        hr = pr.half[2 * t]
        Q[0] = 1.0; Q[1] = 0.0; Q[2] = -al
        Q[3] = 0.0; Q[4] = 1.0; Q[5] = -be
        Q[6] = -al; Q[7] = -be; Q[8] = al * al + be * be - (hr * hr) / (cz * cz)
        qr = pr.QRt + 9 * t
        for a in range(3):
            for b in range(3):
                qr[3 * a + b] = Q[3 * a] * R[3 * b] + Q[3 * a + 1] * R[3 * b + 1] + Q[3 * a + 2] * R[3 * b + 2]
        for a in range(3):
            for b in range(3):
                Ci[3 * a + b] = R[3 * a] * qr[b] + R[3 * a + 1] * qr[3 + b] + R[3 * a + 2] * qr[6 + b]
        pr.c6[6 * t] = Ci[0]
        pr.c6[6 * t + 1] = Ci[1]
        pr.c6[6 * t + 2] = Ci[2]
        pr.c6[6 * t + 3] = Ci[4]
        pr.c6[6 * t + 4] = Ci[5]
        pr.c6[6 * t + 5] = Ci[8]


cdef double evaluate(Prob* pr, const double* p, double* r, double* R, double* dR) noexcept nogil:
    """Whitened residuals r at p (layout in the module doc) and the robust cost; R, dR: Rodrigues
    at p."""
    cdef int i, j, e, t, k, base
    cdef double cost = 0.0, ww, u, v, val, cx0, cx1, h, hh, z, rr, nh0, nh1, nh2
    cdef double* aux
    cdef double X[3]
    cdef double Y[3]
    cdef const double* c6
    cdef const double* C = p + 3
    cdef double fs2 = pr.fs * pr.fs
    rodrigues(p, R, dR)
    if pr.M:
        edge_lines(pr, R, C)
    if pr.N > pr.M:
        circle_conics(pr, R, C)
    for e in range(4 * pr.T if pr.M else 0):
        if pr.estart[e + 1] == pr.estart[e]:
            continue
        nh0 = pr.nh[3 * e]
        nh1 = pr.nh[3 * e + 1]
        nh2 = pr.nh[3 * e + 2]
        for j in range(pr.estart[e], pr.estart[e + 1]):
            i = pr.order[j]
            ww = pr.w[i]
            rr = (pr.P[2 * i] * ww) * nh0 + (pr.P[2 * i + 1] * ww) * nh1 + ww * nh2
            r[i] = rr
            cost += loss_rho(pr.loss, (rr / pr.fs) * (rr / pr.fs))
    for j in range(pr.n_edge_pts, pr.n_edge_pts + pr.N - pr.M):
        i = pr.order[j]
        t = pr.tix[i]
        if pr.flat[t]:
            rr = 1e3
        else:
            c6 = pr.c6 + 6 * t
            u = pr.P[2 * i]
            v = pr.P[2 * i + 1]
            val = u * u * c6[0] + 2.0 * u * v * c6[1] + 2.0 * u * c6[2] + v * v * c6[3] + 2.0 * v * c6[4] + c6[5]
            cx0 = u * c6[0] + v * c6[1] + c6[2]
            cx1 = u * c6[1] + v * c6[3] + c6[4]
            hh = hypot(cx0, cx1)
            h = 2.0 * hh
            rr = val / (h if h > 1e-12 else 1e-12) * pr.w[i]
            aux = r + pr.n_res + 4 * i       # kept for `normal` at this pose
            aux[0] = val
            aux[1] = cx0
            aux[2] = cx1
            aux[3] = hh
        r[i] = rr
        cost += loss_rho(pr.loss, (rr / pr.fs) * (rr / pr.fs))
    base = pr.N
    for k in range(pr.K):
        cam_point(pr.L + 3 * k, C, R, Y, X)
        z = X[2] if X[2] > 1e-6 else 1e-6
        r[base] = (X[0] / z - pr.uv[2 * k]) / pr.sigc
        r[base + 1] = (X[1] / z - pr.uv[2 * k + 1]) / pr.sigc
        cost += loss_rho(pr.loss, (r[base] / pr.fs) * (r[base] / pr.fs))
        cost += loss_rho(pr.loss, (r[base + 1] / pr.fs) * (r[base + 1] / pr.fs))
        base += 2
    if pr.has_up:
        for k in range(3):
            r[base + k] = (R[3 * k + 2] - pr.up[k]) / pr.up_sig
            cost += loss_rho(pr.loss, (r[base + k] / pr.fs) * (r[base + k] / pr.fs))
        base += 3
    if pr.has_prior:
        for k in range(3):
            r[base + k] = pr.W[3 * k] * (C[0] - pr.Cp[0]) + pr.W[3 * k + 1] * (C[1] - pr.Cp[1]) \
                + pr.W[3 * k + 2] * (C[2] - pr.Cp[2])
            cost += loss_rho(pr.loss, (r[base + k] / pr.fs) * (r[base + k] / pr.fs))
    return 0.5 * fs2 * cost


cdef inline void add_row(double* A, double* g, const double* J, double wt, double rr) noexcept nogil:
    """A += wt J J^T (upper triangle), g += wt J rr for one Jacobian row J (6,)."""
    cdef int a, b
    cdef double wa
    for a in range(6):
        wa = wt * J[a]
        g[a] += wa * rr
        for b in range(a, 6):
            A[6 * a + b] += wa * J[b]


cdef inline void add_moments(double* Mc, double* gc, const double* d, double wt, double rr) noexcept nogil:
    """Mc (21: the upper triangle of a 6 x 6, row by row) += wt d d^T, gc (6,) += wt rr d, for one
    point's d r / d c6 (6,), unrolled (the circle points' inner loop)."""
    cdef double w0 = wt * d[0], w1 = wt * d[1], w2 = wt * d[2], w3 = wt * d[3], w4 = wt * d[4], w5 = wt * d[5]
    Mc[0] += w0 * d[0]; Mc[1] += w0 * d[1]; Mc[2] += w0 * d[2]; Mc[3] += w0 * d[3]; Mc[4] += w0 * d[4]
    Mc[5] += w0 * d[5]
    Mc[6] += w1 * d[1]; Mc[7] += w1 * d[2]; Mc[8] += w1 * d[3]; Mc[9] += w1 * d[4]; Mc[10] += w1 * d[5]
    Mc[11] += w2 * d[2]; Mc[12] += w2 * d[3]; Mc[13] += w2 * d[4]; Mc[14] += w2 * d[5]
    Mc[15] += w3 * d[3]; Mc[16] += w3 * d[4]; Mc[17] += w3 * d[5]
    Mc[18] += w4 * d[4]; Mc[19] += w4 * d[5]
    Mc[20] += w5 * d[5]
    gc[0] += w0 * rr; gc[1] += w1 * rr; gc[2] += w2 * rr; gc[3] += w3 * rr; gc[4] += w4 * rr; gc[5] += w5 * rr


cdef void fold_moments(double* A, double* g, const double* Mc, const double* gc, const double* D) noexcept nogil:
    """A (upper triangle) += D Mc D^T, g += D gc for one circle: D (6, 6) row k = d c6 / d p_k
    (`circle_param_jacobians`), Mc (21,) / gc (6,) its points' moments (`add_moments`)."""
    cdef double M[36]
    cdef double T[36]
    cdef int a, b, c, k = 0
    for a in range(6):
        for b in range(a, 6):
            M[6 * a + b] = Mc[k]
            M[6 * b + a] = Mc[k]
            k += 1
    # T = M D^T: T[c, b] = sum_d M[c, d] D[b, d]
    for c in range(6):
        for b in range(6):
            T[6 * c + b] = M[6 * c] * D[6 * b] + M[6 * c + 1] * D[6 * b + 1] + M[6 * c + 2] * D[6 * b + 2] \
                + M[6 * c + 3] * D[6 * b + 3] + M[6 * c + 4] * D[6 * b + 4] + M[6 * c + 5] * D[6 * b + 5]
    for a in range(6):
        g[a] += D[6 * a] * gc[0] + D[6 * a + 1] * gc[1] + D[6 * a + 2] * gc[2] + D[6 * a + 3] * gc[3] \
            + D[6 * a + 4] * gc[4] + D[6 * a + 5] * gc[5]
        for b in range(a, 6):
            A[6 * a + b] += D[6 * a] * T[b] + D[6 * a + 1] * T[6 + b] + D[6 * a + 2] * T[12 + b] \
                + D[6 * a + 3] * T[18 + b] + D[6 * a + 4] * T[24 + b] + D[6 * a + 5] * T[30 + b]


cdef void circle_param_jacobians(Prob* pr, const double* R, const double* dR, const double* C) noexcept nogil:
    """d c6 / d p of every circle seen at an angle (`_Problem._circle_jacobian`): dCi/drvec_k =
    dR_k Q R^T + its transpose, dCi/dC_j = R dQ/dC_j R^T."""
    cdef int t, k, a, b, j
    cdef const double* qr
    cdef double* dc6t
    cdef double X[9]
    cdef double M3[9]
    cdef double tmp[9]
    cdef double dal[3]
    cdef double dbe[3]
    cdef double ds[3]
    cdef double d0, d1, cz, ic, hr
    for t in range(pr.T):
        if not pr.circ[t] or pr.flat[t]:
            continue
        qr = pr.QRt + 9 * t
        dc6t = pr.dc6 + 36 * t
        for k in range(3):
            for a in range(3):
                for b in range(3):
                    X[3 * a + b] = dR[9 * k + 3 * a] * qr[b] + dR[9 * k + 3 * a + 1] * qr[3 + b] \
                        + dR[9 * k + 3 * a + 2] * qr[6 + b]
            dc6t[6 * k] = X[0] + X[0]
            dc6t[6 * k + 1] = X[1] + X[3]
            dc6t[6 * k + 2] = X[2] + X[6]
            dc6t[6 * k + 3] = X[4] + X[4]
            dc6t[6 * k + 4] = X[5] + X[7]
            dc6t[6 * k + 5] = X[8] + X[8]
        d0 = pr.xyz[3 * t] - C[0]
        d1 = pr.xyz[3 * t + 1] - C[1]
        cz = pr.xyz[3 * t + 2] - C[2]
        hr = pr.half[2 * t]
        ic = 1.0 / cz
        dal[0] = -ic; dal[1] = 0.0; dal[2] = d0 * ic * ic
        dbe[0] = 0.0; dbe[1] = -ic; dbe[2] = d1 * ic * ic
        for j in range(3):
            ds[j] = 2.0 * (d0 * ic) * dal[j] + 2.0 * (d1 * ic) * dbe[j]
        ds[2] -= 2.0 * (hr * hr) * (ic * ic * ic)
        for j in range(3):
            for k in range(9):
                M3[k] = 0.0
            M3[2] = M3[6] = -dal[j]
            M3[5] = M3[7] = -dbe[j]
            M3[8] = ds[j]
            for a in range(3):
                for b in range(3):
                    tmp[3 * a + b] = R[3 * a] * M3[b] + R[3 * a + 1] * M3[3 + b] + R[3 * a + 2] * M3[6 + b]
            for a in range(3):
                for b in range(3):
                    X[3 * a + b] = tmp[3 * a] * R[3 * b] + tmp[3 * a + 1] * R[3 * b + 1] + tmp[3 * a + 2] * R[3 * b + 2]
            dc6t[6 * (3 + j)] = X[0]
            dc6t[6 * (3 + j) + 1] = X[1]
            dc6t[6 * (3 + j) + 2] = X[2]
            dc6t[6 * (3 + j) + 3] = X[4]
            dc6t[6 * (3 + j) + 4] = X[5]
            dc6t[6 * (3 + j) + 5] = X[8]


cdef void normal(Prob* pr, const double* p, const double* r, const double* R, const double* dR,
                 double* A, double* g, int gram, double* G) noexcept nogil:
    """`_Problem.normal` (gram=0: IRLS-weighted J^T W J, J^T W r) or `_Problem.gram` (gram=1:
    unweighted J^T J without the position prior's rows) at p, whose residuals r, R and dR
    `evaluate` computed (with the edge / conic work buffers). With gram=1 and G not NULL, G (6, 6)
    also receives `outline_pose._edge_offset_gram`: the sum over the used square / rect edges of
    g g^T, g = dl^T (sum of w^2 (x, y, 1) over the edge's points), from the same per-edge sums."""
    cdef int i, e, t, k, a, b, j, base
    cdef double wp, ww, sx, sy, rr, rho, u, v, val, cx0, cx1, h, hs, kk, sc, z
    cdef const double* aux
    cdef double X[3]
    cdef double Y[3]
    cdef double s0, s1, s2, s3, s4, s5, s6, s7, s8
    cdef double* S
    cdef const double* nh
    cdef const double* m
    cdef const double* d
    cdef const double* C = p + 3
    cdef double dn[18]
    cdef double dl[18]
    cdef double drho[6]
    cdef double SD[18]
    cdef double M3[9]
    cdef double J[6]
    cdef double drdc[6]
    cdef double du[6]
    cdef double dv[6]
    cdef double Mc[21]
    cdef double gc[6]
    cdef int nxt
    for k in range(36):
        A[k] = 0.0
    for k in range(6):
        g[k] = 0.0
    if G != NULL:
        for k in range(36):
            G[k] = 0.0
    if pr.N > pr.M:
        circle_param_jacobians(pr, R, dR, C)
    # Circle points: a point's Jacobian row is drdc^T dc6t (d r / d c6 times the circle's d c6 / d p),
    # so each circle's rows add dc6t^T (sum wp drdc drdc^T) dc6t to A and dc6t^T (sum wp rr drdc)
    # to g: per point a 6-vector and its moments, per circle one 6 x 6 fold (`fold_moments`).
    j = pr.n_edge_pts
    while j < pr.n_edge_pts + pr.N - pr.M:
        t = pr.tix[pr.order[j]]
        nxt = j
        while nxt < pr.n_edge_pts + pr.N - pr.M and pr.tix[pr.order[nxt]] == t:
            nxt += 1
        if pr.flat[t]:
            j = nxt
            continue
        for k in range(21):
            Mc[k] = 0.0
        for k in range(6):
            gc[k] = 0.0
        for j in range(j, nxt):
            i = pr.order[j]
            rr = r[i]
            u = pr.P[2 * i]
            v = pr.P[2 * i + 1]
            aux = r + pr.n_res + 4 * i        # val, the conic's gradient / 2 and its norm at p (`evaluate`)
            val = aux[0]
            cx0 = aux[1]
            cx1 = aux[2]
            h = aux[3]
            hs = h if h > 5e-13 else 5e-13
            kk = val / (hs * hs)
            sc = pr.w[i] / (2.0 * hs)
            drdc[0] = (u * u - (kk * cx0) * u) * sc
            drdc[1] = ((2.0 * u * v - (kk * cx0) * v) - (kk * cx1) * u) * sc
            drdc[2] = (2.0 * u - (kk * cx0)) * sc
            drdc[3] = (v * v - (kk * cx1) * v) * sc
            drdc[4] = (2.0 * v - (kk * cx1)) * sc
            drdc[5] = sc
            wp = 1.0 if gram else loss_w(pr.loss, (rr / pr.fs) * (rr / pr.fs))
            add_moments(Mc, gc, drdc, wp, rr)
        fold_moments(A, g, Mc, gc, pr.dc6 + 36 * t)
        j = nxt
    # Square / rect points: per-edge moments of the whitened rows (x, y, 1) w, then dl^T S dl.
    for e in range(4 * pr.T if pr.M else 0):
        if pr.estart[e + 1] == pr.estart[e]:
            continue
        s0 = s1 = s2 = s3 = s4 = s5 = s6 = s7 = s8 = 0.0
        for j in range(pr.estart[e], pr.estart[e + 1]):
            i = pr.order[j]
            rr = r[i]
            wp = 1.0 if gram else loss_w(pr.loss, (rr / pr.fs) * (rr / pr.fs))
            ww = pr.w[i]
            sx = pr.P[2 * i] * ww
            sy = pr.P[2 * i + 1] * ww
            s0 += sx * sx * wp
            s1 += sx * sy * wp
            s2 += sx * ww * wp
            s3 += sy * sy * wp
            s4 += sy * ww * wp
            s5 += ww * ww * wp
            s6 += sx * (wp * rr)
            s7 += sy * (wp * rr)
            s8 += ww * (wp * rr)
        S = pr.S + 9 * e
        S[0] = s0; S[1] = s1; S[2] = s2; S[3] = s3; S[4] = s4; S[5] = s5; S[6] = s6; S[7] = s7; S[8] = s8
    for e in range(4 * pr.T if pr.M else 0):
        if pr.estart[e + 1] == pr.estart[e]:
            continue          # no point on this edge
        S = pr.S + 9 * e
        m = pr.m + 3 * e
        nh = pr.nh + 3 * e
        d = pr.D + 3 * e
        rho = pr.rho[e]
        # dn[a*6 + k]: d n_a / d rvec_k = (dRk[k] m)_a ; d n_a / d C_j = (R (e_j x D))_a
        for a in range(3):
            for k in range(3):
                dn[6 * a + k] = dR[9 * k + 3 * a] * m[0] + dR[9 * k + 3 * a + 1] * m[1] + dR[9 * k + 3 * a + 2] * m[2]
            # e_0 x D = (0, -D2, D1), e_1 x D = (D2, 0, -D0), e_2 x D = (-D1, D0, 0)
            dn[6 * a + 3] = R[3 * a + 1] * (-d[2]) + R[3 * a + 2] * d[1]
            dn[6 * a + 4] = R[3 * a] * d[2] + R[3 * a + 2] * (-d[0])
            dn[6 * a + 5] = R[3 * a] * (-d[1]) + R[3 * a + 1] * d[0]
        for k in range(6):
            drho[k] = (nh[0] * dn[k] + nh[1] * dn[6 + k]) / rho
        for a in range(3):
            for k in range(6):
                dl[6 * a + k] = dn[6 * a + k] / rho - nh[a] * drho[k]
        M3[0] = S[0]; M3[1] = S[1]; M3[2] = S[2]
        M3[3] = S[1]; M3[4] = S[3]; M3[5] = S[4]
        M3[6] = S[2]; M3[7] = S[4]; M3[8] = S[5]
        for a in range(3):
            for k in range(6):
                SD[6 * a + k] = M3[3 * a] * dl[k] + M3[3 * a + 1] * dl[6 + k] + M3[3 * a + 2] * dl[12 + k]
        for a in range(6):
            g[a] += dl[a] * S[6] + dl[6 + a] * S[7] + dl[12 + a] * S[8]
            for b in range(a, 6):
                A[6 * a + b] += dl[a] * SD[b] + dl[6 + a] * SD[6 + b] + dl[12 + a] * SD[12 + b]
        if G != NULL:
            # the edge's common-offset row: (x w^2, y w^2, w^2) summed (S[2], S[4], S[5]) through dl
            for k in range(6):
                J[k] = S[2] * dl[k] + S[4] * dl[6 + k] + S[5] * dl[12 + k]
            for a in range(6):
                for b in range(a, 6):
                    G[6 * a + b] += J[a] * J[b]
    base = pr.N
    # Centroids.
    for k in range(pr.K):
        cam_point(pr.L + 3 * k, C, R, Y, X)
        z = X[2] if X[2] > 1e-6 else 1e-6
        for j in range(3):
            # dX_a / d rvec_j = (dRk[j] Y)_a ; dX_a / d C_j = -R_aj
            dn[j] = dR[9 * j] * Y[0] + dR[9 * j + 1] * Y[1] + dR[9 * j + 2] * Y[2]
            dn[6 + j] = dR[9 * j + 3] * Y[0] + dR[9 * j + 4] * Y[1] + dR[9 * j + 5] * Y[2]
            dn[12 + j] = dR[9 * j + 6] * Y[0] + dR[9 * j + 7] * Y[1] + dR[9 * j + 8] * Y[2]
            dn[3 + j] = -R[j]
            dn[9 + j] = -R[3 + j]
            dn[15 + j] = -R[6 + j]
        for j in range(6):
            du[j] = (dn[j] - (X[0] / z) * dn[12 + j]) / z / pr.sigc
            dv[j] = (dn[6 + j] - (X[1] / z) * dn[12 + j]) / z / pr.sigc
        rr = r[base]
        add_row(A, g, du, 1.0 if gram else loss_w(pr.loss, (rr / pr.fs) * (rr / pr.fs)), rr)
        rr = r[base + 1]
        add_row(A, g, dv, 1.0 if gram else loss_w(pr.loss, (rr / pr.fs) * (rr / pr.fs)), rr)
        base += 2
    if pr.has_up:
        for a in range(3):
            for k in range(3):
                J[k] = dR[9 * k + 3 * a + 2] / pr.up_sig
                J[3 + k] = 0.0
            rr = r[base + a]
            add_row(A, g, J, 1.0 if gram else loss_w(pr.loss, (rr / pr.fs) * (rr / pr.fs)), rr)
        base += 3
    if pr.has_prior and not gram:
        for a in range(3):
            J[0] = J[1] = J[2] = 0.0
            J[3] = pr.W[3 * a]
            J[4] = pr.W[3 * a + 1]
            J[5] = pr.W[3 * a + 2]
            rr = r[base + a]
            add_row(A, g, J, loss_w(pr.loss, (rr / pr.fs) * (rr / pr.fs)), rr)
    for a in range(6):
        for b in range(a):
            A[6 * a + b] = A[6 * b + a]
            if G != NULL:
                G[6 * a + b] = G[6 * b + a]


cdef int lm(Prob* pr, double* p, double** rp, double* R, double* dR, double** rp_new, double* R_new,
            double* dR_new, int max_iter, double step_tol, double cost_rtol) noexcept nogil:
    """Levenberg-Marquardt (`lm_damping`, `lm_step`) with the outline stopping rule
    (outline_pose.STEP_TOL, COST_RTOL): p, R, dR and the residual buffer *rp end at the returned
    pose (an accepted step swaps *rp and *rp_new instead of copying the buffers). Returns 1 when
    converged."""
    cdef double A[36]
    cdef double g[6]
    cdef double mg[6]
    cdef double dA[6]
    cdef double dp[6]
    cdef double p_new[6]
    cdef double lam = 1e-3, c, c_new, mx
    cdef int it, k, stop
    cdef double* r = rp[0]
    cdef double* r_new = rp_new[0]
    c = evaluate(pr, p, r, R, dR)
    for it in range(max_iter):
        normal(pr, p, r, R, dR, A, g, 0, NULL)
        lm_damping(A, dA)
        for k in range(6):
            mg[k] = -g[k]
        while True:
            lm_step(A, dA, mg, lam, p, dp, p_new)
            c_new = evaluate(pr, p_new, r_new, R_new, dR_new)
            if c_new <= c:
                break
            lam *= 10.0
            if lam > 1e8:
                evaluate(pr, p, r, R, dR)     # (restore the edge / conic work buffers at p)
                rp[0], rp_new[0] = r, r_new
                return 1
        mx = 0.0
        for k in range(6):
            if fabs(dp[k]) > mx or dp[k] != dp[k]:
                mx = fabs(dp[k])
        stop = 1 if (mx <= step_tol or c - c_new <= cost_rtol * c) else 0
        for k in range(6):
            p[k] = p_new[k]
        r, r_new = r_new, r
        for k in range(9):
            R[k] = R_new[k]
        for k in range(27):
            dR[k] = dR_new[k]
        c = c_new
        lam = lam / 10.0
        if lam < 1e-12:
            lam = 1e-12
        if stop:
            rp[0], rp_new[0] = r, r_new
            return 1
    rp[0], rp_new[0] = r, r_new
    return 0


def solve(double[::1] p, int[::1] lab, const double[:, ::1] P, const double[::1] sigma, const long long[::1] ends,
          const double[:, ::1] xyz, const double[:, ::1] half, const int[::1] circ, const double[:, ::1] uv,
          double sigc, const double[::1] up, double up_sig, const double[::1] Cp,
          const double[:, ::1] W, int loss, double f_scale, int rounds, int max_iter, double guard2,
          int minor_switches, double minor_fraction, double step_tol, double cost_rtol,
          double[:, ::1] R_out, double[:, ::1] gram_out, double[:, ::1] offset_out=None):
    """`solve_outline_pose`'s rounds (edge assignment, then at most `max_iter` LM iterations) from
    p (6,), updated in place, on an `OutlineFrame`'s arrays: targets `xyz` (T, 3) centres, `half`
    (T, 2) half extents along world x, y, `circ` (T,) 1 for a circle, `uv` (T, 2) centroids (NaN:
    none); points `P` (N, 2) of 1-sigma `sigma`, target k's from `ends[k]` to `ends[k + 1]`.
    `lab` (N,) receives the final edge labels, `R_out` (3, 3) R_cw at p, `gram_out` (6, 6) the
    unweighted J^T J without the position prior, `offset_out` (6, 6, or None) the edge-offset
    gram at p (`outline_pose._edge_offset_gram` of the final labels; `normal`). `up` / `Cp` empty: no tilt / position prior.
    Returns (converged, chi^2 without the position prior's rows, residual count without them)."""
    cdef Prob pr
    cdef int N = P.shape[0], T = xyz.shape[0]
    cdef int i, j, k, t, n, nxt, converged = 0, changed, first = 1, n_use = 0, M = 0, K = 0
    cdef double chi2 = 0.0
    cdef double R[9]
    cdef double dR[27]
    cdef double R_new[9]
    cdef double dR_new[27]
    cdef double A[36]
    cdef double g[6]
    cdef double Go[36]
    cdef double* Gp = NULL
    cdef double sgn[8]
    cdef double* r
    cdef double* r_new
    cdef double* work
    cdef double* wbuf
    cdef double* a
    cdef double* b
    cdef int* iwork
    cdef int* tix
    if P.shape[1] != 2 or sigma.shape[0] != N or lab.shape[0] != N or half.shape[0] != T \
            or circ.shape[0] != T or uv.shape[0] != T or ends.shape[0] != T + 1 or p.shape[0] != 6 \
            or (T and (ends[0] != 0 or ends[T] != N)):
        raise ValueError("inconsistent outline arrays")
    if offset_out is not None:
        if offset_out.shape[0] != 6 or offset_out.shape[1] != 6:
            raise ValueError("offset_out must be 6 x 6")
        Gp = Go
    for t in range(T):
        if ends[t + 1] < ends[t]:
            raise ValueError("outline target ends must not decrease")
        if not circ[t]:
            M += <int> (ends[t + 1] - ends[t])
        if uv[t, 0] == uv[t, 0]:
            K += 1
    pr.N, pr.M, pr.T, pr.K = N, M, T, K
    pr.P = &P[0, 0] if N else NULL
    pr.lab = &lab[0] if N else NULL
    pr.circ = &circ[0] if T else NULL
    pr.xyz = &xyz[0, 0] if T else NULL
    pr.half = &half[0, 0] if T else NULL
    pr.sigc = sigc
    pr.has_up = 1 if up.shape[0] == 3 else 0
    for k in range(3):
        pr.up[k] = up[k] if pr.has_up else 0.0
    pr.up_sig = up_sig
    pr.has_prior = 1 if Cp.shape[0] == 3 else 0
    for k in range(3):
        pr.Cp[k] = Cp[k] if pr.has_prior else 0.0
    for k in range(9):
        pr.W[k] = W[k // 3, k % 3] if pr.has_prior else 0.0
    pr.loss = loss
    pr.fs = f_scale
    n = N + 2 * K + 3 * pr.has_up + 3 * pr.has_prior
    pr.n_res = n
    pr.n_buf = n + 4 * N
    work = <double*> malloc((2 * pr.n_buf + 4 * T * (3 + 3 + 3 + 3 + 1 + 3 + 9) + T * (6 + 9 + 36) + 5 * K + 1)
                            * sizeof(double))
    iwork = <int*> malloc((T + 1 + N + 4 * T + 1 + N) * sizeof(int))
    wbuf = <double*> malloc((N + 1) * sizeof(double))
    if work == NULL or iwork == NULL or wbuf == NULL:
        free(wbuf)
        free(work)
        free(iwork)
        raise MemoryError()
    r = work
    r_new = work + pr.n_buf
    pr.corners = r_new + pr.n_buf
    pr.AxB = pr.corners + 12 * T
    pr.D = pr.AxB + 12 * T
    pr.nh = pr.D + 12 * T
    pr.rho = pr.nh + 12 * T
    pr.m = pr.rho + 4 * T
    pr.S = pr.m + 12 * T
    pr.c6 = pr.S + 36 * T
    pr.QRt = pr.c6 + 6 * T
    pr.dc6 = pr.QRt + 9 * T
    pr.L = pr.dc6 + 36 * T
    pr.uv = pr.L + 3 * K
    pr.flat = iwork
    pr.order = iwork + T + 1
    pr.estart = pr.order + N
    tix = pr.estart + 4 * T + 1
    for t in range(T):
        for i in range(<int> ends[t], <int> ends[t + 1]):
            tix[i] = t
    for i in range(N):
        wbuf[i] = 1.0 / sigma[i]          # the numpy path's 1.0 / sigma
    pr.tix = tix
    pr.w = wbuf
    memset(r, 0, n * sizeof(double))               # (the circles' terms are written before they are read)
    memset(r_new, 0, n * sizeof(double))
    pr.n_edge_pts = 0
    with nogil:
        # Corners of the squares / rects (`_corners`: +x+y, -x+y, -x-y, +x-y), their edges A -> B.
        sgn[0] = 1.0; sgn[1] = 1.0; sgn[2] = -1.0; sgn[3] = 1.0
        sgn[4] = -1.0; sgn[5] = -1.0; sgn[6] = 1.0; sgn[7] = -1.0
        k = 0
        for t in range(T):
            pr.flat[t] = 0
            if uv[t, 0] == uv[t, 0]:
                for j in range(3):
                    pr.L[3 * k + j] = xyz[t, j]
                pr.uv[2 * k] = uv[t, 0]
                pr.uv[2 * k + 1] = uv[t, 1]
                k += 1
            for j in range(4):
                a = pr.corners + 3 * (4 * t + j)
                a[0] = xyz[t, 0] + sgn[2 * j] * half[t, 0]
                a[1] = xyz[t, 1] + sgn[2 * j + 1] * half[t, 1]
                a[2] = xyz[t, 2] + 0.0
            for j in range(4):
                nxt = 4 * t + (j + 1) % 4
                a = pr.corners + 3 * (4 * t + j)
                b = pr.corners + 3 * nxt
                pr.AxB[3 * (4 * t + j)] = a[1] * b[2] - a[2] * b[1]
                pr.AxB[3 * (4 * t + j) + 1] = a[2] * b[0] - a[0] * b[2]
                pr.AxB[3 * (4 * t + j) + 2] = a[0] * b[1] - a[1] * b[0]
                for i in range(3):
                    pr.D[3 * (4 * t + j) + i] = a[i] - b[i]
        for k in range(rounds):
            changed = assign(&pr, &p[0], 1 if (k > 0 and converged) else 0, first, guard2,
                             minor_switches, minor_fraction)
            if first or changed:
                group(&pr)
                for i in range(N):
                    if not pr.circ[pr.tix[i]] and pr.lab[i] < 0:
                        r[i] = 0.0
                        r_new[i] = 0.0
            first = 0
            if k > 0 and converged and not changed:
                break
            converged = lm(&pr, &p[0], &r, R, dR, &r_new, R_new, dR_new, max_iter, step_tol, cost_rtol)
        for i in range(N):
            if pr.circ[pr.tix[i]] or pr.lab[i] >= 0:
                chi2 += r[i] * r[i]
                n_use += 1
        for i in range(N, n - 3 * pr.has_prior):
            chi2 += r[i] * r[i]
        normal(&pr, &p[0], r, R, dR, A, g, 1, Gp)
    for k in range(9):
        R_out[k // 3, k % 3] = R[k]
    for k in range(36):
        gram_out[k // 6, k % 6] = A[k]
    if Gp != NULL:
        for k in range(36):
            offset_out[k // 6, k % 6] = Go[k]
    free(work)
    free(iwork)
    free(wbuf)
    return converged, chi2, n_use + 2 * K + 3 * pr.has_up



def spd_inverse(const double[:, ::1] A, double[:, ::1] out, double min_pivot_ratio):
    """out = A^-1 of a symmetric positive definite 6 x 6 matrix by Cholesky (A = L L^T, then
    L^-T L^-1); False (out untouched) where a pivot L_kk^2 is not above `min_pivot_ratio` times
    the largest diagonal entry (singular or ill-conditioned: the caller's pseudo-inverse then)."""
    cdef double L[36]
    cdef double Li[36]
    cdef double acc, dmax = 0.0
    cdef int i, j, k
    if A.shape[0] != 6 or A.shape[1] != 6 or out.shape[0] != 6 or out.shape[1] != 6:
        raise ValueError("spd_inverse takes 6 x 6 matrices")
    for i in range(6):
        if A[i, i] > dmax:
            dmax = A[i, i]
    if not (dmax > 0.0) or dmax != dmax or dmax > 1.7e308:
        return False
    for i in range(36):
        L[i] = 0.0
        Li[i] = 0.0
    for j in range(6):
        acc = A[j, j]
        for k in range(j):
            acc -= L[6 * j + k] * L[6 * j + k]
        if not (acc > min_pivot_ratio * dmax):
            return False
        L[6 * j + j] = sqrt(acc)
        for i in range(j + 1, 6):
            acc = A[i, j]
            for k in range(j):
                acc -= L[6 * i + k] * L[6 * j + k]
            L[6 * i + j] = acc / L[6 * j + j]
    # Li = L^-1 (lower triangular)
    for j in range(6):
        Li[6 * j + j] = 1.0 / L[6 * j + j]
        for i in range(j + 1, 6):
            acc = 0.0
            for k in range(j, i):
                acc -= L[6 * i + k] * Li[6 * k + j]
            Li[6 * i + j] = acc / L[6 * i + i]
    # out = Li^T Li
    for i in range(6):
        for j in range(i, 6):
            acc = 0.0
            for k in range(j, 6):
                acc += Li[6 * k + i] * Li[6 * k + j]
            out[i, j] = acc
            out[j, i] = acc
    return True
