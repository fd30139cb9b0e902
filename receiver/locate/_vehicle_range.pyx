# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False
"""Compiled per-pair ranging loop of the vehicle stage (receiver.locate.vehicle.range_core and
`_area_range`, the pure reference). The same scalar IEEE operations in the same order (no FMA
contraction, no reassociation), so the numbers are the Python loop's to the last bit; NaN where
the Python helpers `_sqrt` / `_div` give NaN, Python's max(a, b) (a unless b > a)."""

from libc.math cimport sqrt, fabs, isfinite, copysign, M_PI, NAN, INFINITY

cdef double SQRT2 = sqrt(2.0)


cdef inline double _sqrt(double x) noexcept nogil:
    return sqrt(x) if x >= 0.0 else NAN


cdef inline double _div(double a, double b) noexcept nogil:
    if b == 0.0:
        if a != a or a == 0.0:
            return NAN
        return copysign(INFINITY, a) * copysign(1.0, b)
    return a / b


cdef inline double pymax(double a, double b) noexcept nogil:
    return b if b > a else a


cdef void area_range(double rx, double ry, double rz, double cos3, double eta, double j, double A,
                     double s1x, double s1y, double s1z, double s2x, double s2y, double s2z, bint circle,
                     double nx, double ny, double nz, double osig, double off, double edge_sigma,
                     double* out) noexcept nogil:
    """vehicle._area_range: out = (d, ea, eb)."""
    cdef double k1 = s1x * rx + s1y * ry + s1z * rz
    cdef double k2 = s2x * rx + s2y * ry + s2z * rz
    cdef double p1x = s1x - k1 * rx, p1y = s1y - k1 * ry, p1z = s1z - k1 * rz
    cdef double p2x = s2x - k2 * rx, p2y = s2y - k2 * ry, p2z = s2z - k2 * rz
    cdef double l1 = sqrt(p1x * p1x + p1y * p1y + p1z * p1z)
    cdef double l2 = sqrt(p2x * p2x + p2y * p2y + p2z * p2z)
    cdef double cx = p1y * p2z - p1z * p2y, cy = p1z * p2x - p1x * p2z, cz = p1x * p2y - p1y * p2x
    cdef double ar = sqrt(cx * cx + cy * cy + cz * cz)
    cdef double kperim, sq_eta, eta_c, cos_th, d, tan_th
    if circle:
        kperim = _div((M_PI / 2) * (l1 + l2), sqrt(M_PI * ar / 4))
    else:
        kperim = _div(2.0 * (l1 + l2), sqrt(ar))
    sq_eta = _sqrt(pymax(eta, 0.0))
    eta_c = eta + kperim * sq_eta * off + M_PI * off * off if off != 0.0 else eta
    cos_th = fabs(nx * rx + ny * ry + nz * rz)
    d = _sqrt(_div(A * cos_th, eta_c * j * cos3)) if eta > 0 and cos_th > 1e-3 else NAN
    tan_th = _div(_sqrt(pymax(1.0 - cos_th * cos_th, 0.0)), pymax(cos_th, 1e-3))
    out[0] = d
    out[1] = _div(edge_sigma * kperim, 2.0 * sq_eta)
    out[2] = 0.5 * tan_th * osig


def range_rows(list ja, list jb, list eta_a, list eta_b, list area_m2, list osig_l, list bm_l, list amr_l,
               list csig_l, list ua, list ub, list S1, list S2, list B_cam, list n_cam, list circle, list ra,
               list rb, list cos3a, list cos3b, double focal_px, double off, double esig, double cons):
    """The loop of vehicle.range_core over its per-pair columns (Python lists: floats, or rows of
    2 / 3 floats): the 15 output columns as lists ("eq18" .. "area_clash", range_core's keys)."""
    cdef Py_ssize_t n = len(ja), i
    cols_in = (jb, eta_a, eta_b, area_m2, osig_l, bm_l, amr_l, csig_l, ua, ub, S1, S2, B_cam, n_cam, circle,
               ra, rb, cos3a, cos3b)
    if any(len(c) != n for c in cols_in):     # the loop indexes the lists unchecked (boundscheck=False)
        raise ValueError("range_rows: every column needs len(ja) entries")
    cdef double ja_i, jb_i, eta_a_i, eta_b_i, A, osig, bm, amr_i, csig_i, uax, uay, ubx, uby
    cdef double s1x, s1y, s1z, s2x, s2y, s2z, bx, by, bz, nx, ny, nz, rax, ray, raz, rbx, rby, rbz, c3a, c3b
    cdef double umx, umy, dux, duy, rab, ba, bb, det, sa, sb, px, py, pz, d_base, sep_px, s_base
    cdef double d18, s18, pax, pay, paz, d_ob, fore, s_ob, wa, wb, wsum, d_f, s_f, amr2
    cdef double oa[3]
    cdef double ob[3]
    cdef bint circ, flip, fa, fb, clash
    cols = [[] for _ in range(15)]
    for i in range(n):
        ja_i = ja[i]
        jb_i = jb[i]
        eta_a_i = eta_a[i]
        eta_b_i = eta_b[i]
        A = area_m2[i]
        osig = osig_l[i]
        bm = bm_l[i]
        amr_i = amr_l[i]
        csig_i = csig_l[i]
        uax, uay = ua[i]
        ubx, uby = ub[i]
        s1x, s1y, s1z = S1[i]
        s2x, s2y, s2z = S2[i]
        bx, by, bz = B_cam[i]
        nx, ny, nz = n_cam[i]
        circ = circle[i]
        rax, ray, raz = ra[i]
        rbx, rby, rbz = rb[i]
        c3a = cos3a[i]
        c3b = cos3b[i]
        umx, umy = 0.5 * (uax + ubx), 0.5 * (uay + uby)
        dux, duy = ubx - uax, uby - uay
        flip = (bx - umx * bz) * dux + (by - umy * bz) * duy < 0
        if flip:
            bx, by, bz = -bx, -by, -bz
        rab = rax * rbx + ray * rby + raz * rbz
        ba = -(rax * bx + ray * by + raz * bz)
        bb = rbx * bx + rby * by + rbz * bz
        det = 1.0 - rab * rab
        sa = _div(ba + rab * bb, det)
        sb = _div(bb + rab * ba, det)
        px, py, pz = sa * rax + sb * rbx, sa * ray + sb * rby, sa * raz + sb * rbz
        d_base = 0.5 * _sqrt(px * px + py * py + pz * pz)
        sep_px = sqrt(dux * dux + duy * duy) * focal_px
        s_base = d_base * (_div(SQRT2 * csig_i, sep_px) + bm)
        if not (det > 1e-14 and sa > 0 and sb > 0):
            d_base = NAN
        area_range(rax, ray, raz, c3a, eta_a_i, ja_i, A, s1x, s1y, s1z, s2x, s2y, s2z, circ, nx, ny, nz, osig,
                   off, esig, oa)
        area_range(rbx, rby, rbz, c3b, eta_b_i, jb_i, A, s1x, s1y, s1z, s2x, s2y, s2z, circ, nx, ny, nz, osig,
                   off, esig, ob)
        if eta_a_i > 0 and eta_b_i > 0:
            d18 = 0.5 * focal_px * (_sqrt(_div(A, eta_a_i)) + _sqrt(_div(A, eta_b_i)))
        else:
            d18 = NAN
        s18 = d18 * (amr_i + 0.5 * (oa[1] + ob[1]))
        if not isfinite(s18):
            d18 = NAN
        pax, pay, paz = 0.5 * (oa[0] * rax + ob[0] * rbx), 0.5 * (oa[0] * ray + ob[0] * rby), 0.5 * (oa[0] * raz + ob[0] * rbz)
        d_ob = _sqrt(pax * pax + pay * pay + paz * paz)
        fore = 0.5 * (oa[2] + ob[2])
        s_ob = d_ob * _sqrt((oa[1] * oa[1] + ob[1] * ob[1]) / 4 + fore * fore + amr_i * amr_i)
        wa = _div(1.0, s_ob * s_ob)
        wb = _div(1.0, s_base * s_base)
        fa = isfinite(d_ob) and isfinite(wa)
        fb = isfinite(d_base) and isfinite(wb)
        clash = fa and fb and fabs(d_ob - d_base) > cons * _sqrt(s_ob * s_ob + s_base * s_base)
        fa = fa and not clash
        wa = wa if fa else 0.0
        wb = wb if fb else 0.0
        wsum = wa + wb
        if wsum > 0:
            d_f = (wa * (d_ob if fa else 0.0) + wb * (d_base if fb else 0.0)) / wsum
            s_f = 1.0 / sqrt(wsum)
        else:
            d_f = NAN
            s_f = NAN
        amr2 = amr_i * amr_i
        cols[0].append(d18)
        cols[1].append(s18)
        cols[2].append(d_ob)
        cols[3].append(s_ob)
        cols[4].append(d_base)
        cols[5].append(s_base)
        cols[6].append(d_f)
        cols[7].append(s_f)
        cols[8].append(oa[0])
        cols[9].append(ob[0])
        cols[10].append(oa[0] * _sqrt(oa[1] * oa[1] + oa[2] * oa[2] + amr2))
        cols[11].append(ob[0] * _sqrt(ob[1] * ob[1] + ob[2] * ob[2] + amr2))
        cols[12].append(bool(flip))
        cols[13].append(bool(fb and not fa))
        cols[14].append(bool(clash))
    return cols


def rays(double[:, ::1] u, double[:, ::1] out):
    """vehicle._rays: unit rays (x, y, 1) / |(x, y, 1)| of normalized points u (N, 2) into out
    (N, 3); the squared norm summed as numpy's row reduction does, (x^2 + y^2) + 1."""
    cdef Py_ssize_t i
    cdef double x, y, n
    for i in range(u.shape[0]):
        x = u[i, 0]
        y = u[i, 1]
        n = sqrt((x * x + y * y) + 1.0 * 1.0)
        out[i, 0] = x / n
        out[i, 1] = y / n
        out[i, 2] = 1.0 / n


from libc.math cimport floor

cdef double[5] POW10 = [1.0, 10.0, 100.0, 1000.0, 10000.0]


def rnd(v, int nd=4):
    """vehicle._r: None for None or a non-finite v, else Python's round(float(v), nd) (0 <= nd <=
    4), bit for bit: the nearest double to the decimal m 10^-nd, m = |v| 10^nd rounded, taken as
    m / 10^nd (one correctly rounded division) with v's sign, when |v| 10^nd is clear of a
    rounding tie by far more than its own rounding error; else round() itself (its digit
    conversion is most of the vehicle record's cost)."""
    if v is None:
        return None
    cdef double x = v, ax, y, f, m, p
    if not isfinite(x):
        return None
    if nd < 0 or nd > 4:
        return round(<object>x, nd)
    p = POW10[nd]
    ax = fabs(x)
    y = ax * p
    if y < 1e12:
        f = y - floor(y)
        if fabs(f - 0.5) > 1e-12 * y + 1e-12:
            m = floor(y) + (1.0 if f > 0.5 else 0.0)
            return copysign(m / p, x)
    return round(<object>x, nd)


def pose_ranges(list pairs, dict heads, double cx, double cy, double cz, double c00, double c01, double c10,
                double c11, double hs, list ranges):
    """VehicleLocator._pose_ranges' loop: ranges[i] = (d, sigma, "pose") of each street-light
    pair whose mapped head (`heads`: led_id -> (x, y, z) of the lights with emitters) is known,
    from the camera centre C and its position covariance (2 x 2); the same scalar operations."""
    cdef Py_ssize_t i
    cdef double hx, hy, hz, vx, vy, vz, d, ux, uy, q, t
    if len(ranges) < len(pairs):              # written unchecked (boundscheck=False)
        raise ValueError("pose_ranges: ranges needs one entry per pair")
    for i in range(len(pairs)):
        p = pairs[i]
        led = p.led_id
        if not (p.kind == "SL" or (led is not None and led <= 0x7F)):
            continue
        h = heads.get(led)
        if h is None:
            continue
        hx, hy, hz = h
        vx, vy, vz = hx - cx, hy - cy, hz - cz
        d = sqrt(vx * vx + vy * vy + vz * vz)
        ux, uy = vx / d, vy / d
        q = ux * (ux * c00 + uy * c10) + uy * (ux * c01 + uy * c11)
        t = hs * vz / d
        ranges[i] = (d, sqrt(pymax(q, 0.0) + t * t * 0.01), "pose")


cdef inline double min_d2(double[:, ::1] P, double ux, double uy) noexcept nogil:
    """np.min((P - u)[:, 0]^2 + (P - u)[:, 1]^2), NaN when any is NaN (numpy's min)."""
    cdef Py_ssize_t i
    cdef double dx, dy, v, m = INFINITY
    for i in range(P.shape[0]):
        dx = P[i, 0] - ux
        dy = P[i, 1] - uy
        v = dx * dx + dy * dy
        if v != v:
            return v
        if v < m:
            m = v
    return m


def near_any(double[:, ::1] P, double ax, double ay, double bx, double by, double g2):
    """VehicleLocator._on_mapped_sl's test: whether point a or b (normalized) is within sqrt(g2)
    of any row of P (m >= 1, 2), as its numpy form decides it."""
    if P.shape[1] != 2:
        raise ValueError("near_any: P needs 2 columns")
    return min_d2(P, ax, ay) < g2 or min_d2(P, bx, by) < g2
