"""GFFE's camera geometry (fgcli.ops.gffe.unproject / project) per pixel: the same float32
operations in the same order as the torch functions (every product and sum rounded on its
own, the matrix coefficients rounded to float32 as torch rounds a Python scalar, Python's
``sum`` starting from 0), so the results are bit-identical: multiplications, additions and
divisions are correctly rounded everywhere (no FMA: numba does not contract without
fastmath, and torch's add/sub FMA has alpha +-1, exact).

The one exception is the square root of the sky directions' norm: torch.sqrt on the CPU is
MKL's vsSqrt (high-accuracy mode, not correctly rounded: ~0.6 % of float32 values differ
from IEEE sqrt by one ulp), which a kernel cannot reproduce. Only sky pixels (+inf depth)
use that norm, so the kernels leave them for a second pass: the first pass writes the
squared norm of every pixel and counts the sky pixels per row; fgcli.kernels.ops takes
torch.sqrt of the rows that have sky (the very function the reference calls, element by
element), and the sky pass finishes those pixels.

A fused unproject + project (no positions written) was measured slower than the two
kernels one after the other (its larger body vectorises worse), so there is none.

A pixel's ray (unproject's near point and near-to-far vector) costs six of the seven
divisions of its unprojection. On a grid of samples (one row of x for all rows, one y per
row) and a projection whose inverse keeps x and y apart (perspective, off-axis,
orthographic), the ray's x parts depend on the column alone and its y parts on the row
alone, bit for bit: ray_tables makes them once per call (w + h rays) and the pixel loops
read them (reproject_kernel 1.3x faster, identical outputs). Any other
camera or sample layout takes the per-pixel rays.

The per-pixel bodies are selects, no branches (they vectorise). The matrix coefficients
come in as tuples of float32 scalars (fgcli.kernels.ops computes them in float64 exactly as
the torch functions do; scalars, not arrays: loads from an array the kernel might write
would not be hoisted out of the pixel loop)."""
from __future__ import annotations

import numpy as np
from numba import njit, prange

from fgcli.kernels._common import INF, INLINE, KERNEL

TINY = np.float32(1e-30)  # unproject's guards (torch compares in float32)
EPS_W = np.float32(1e-12)  # project's clip-w threshold
OFF = np.float32(1.0e6)  # fgcli.ops.gffe.OFF
SKY_SPAN = 64  # the sky passes skip runs of this many pixels that hold no sky
ZERO = np.float32(0.0)
ONE = np.float32(1.0)
U0 = np.uint8(0)


# ----------------------------------------------------------------------------- unproject

@njit(**INLINE)
def _at(nx, ny, A, k):
    """unproject's at(zn): the view-space point on the NDC ray (nx, ny); A holds the
    (ip[i, 0], ip[i, 1], c[i]) of at(-1) (k = 0) and at(1) (k = 12)."""
    p0 = (nx * A[k] + ny * A[k + 1]) + A[k + 2]
    p1 = (nx * A[k + 3] + ny * A[k + 4]) + A[k + 5]
    p2 = (nx * A[k + 6] + ny * A[k + 7]) + A[k + 8]
    wv = (nx * A[k + 9] + ny * A[k + 10]) + A[k + 11]
    wv = TINY if abs(wv) < TINY else wv
    return p0 / wv, p1 / wv, p2 / wv


@njit(**INLINE)
def _ray(nx, ny, A):
    """Near point (n0, n1, n2) and near-to-far vector (v0, v1, v2) of an NDC ray."""
    n0, n1, n2 = _at(nx, ny, A, 0)
    f0, f1, f2 = _at(nx, ny, A, 12)
    return n0, n1, n2, f0 - n0, f1 - n1, f2 - n2


@njit(**INLINE)
def _nan0(v):
    """nan_to_num(nan=0, posinf=0, neginf=0)."""
    return v if abs(v) < INF else ZERO


@njit(**INLINE)
def _surface_ray(n0, n1, n2, v0, v1, v2, d, M):
    """_surface_px of the ray (near point n, near-to-far vector v) at depth d."""
    finite = (d > ZERO) & (d < INF)
    dz = -TINY if abs(v2) < TINY else v2
    s = ((-d) - n2) / dz
    s = s if finite else ZERO
    w0 = n0 + v0 * s
    w1 = n1 + v1 * s
    w2 = n2 + v2 * s
    o0 = (((ZERO + M[0] * w0) + M[1] * w1) + M[2] * w2) + M[3]
    o1 = (((ZERO + M[4] * w0) + M[5] * w1) + M[6] * w2) + M[7]
    o2 = (((ZERO + M[8] * w0) + M[9] * w1) + M[10] * w2) + M[11]
    o0 = _nan0(o0 if finite else ZERO)
    o1 = _nan0(o1 if finite else ZERO)
    o2 = _nan0(o2 if finite else ZERO)
    return o0, o1, o2, (ONE if finite else ZERO), (v0 * v0 + v1 * v1) + v2 * v2


@njit(**INLINE)
def _surface_px(nx, ny, d, A, M):
    """unproject of one pixel, the sky left out: (x, y, z, w) of a surface (finite depth
    > 0), zeros elsewhere (sky included), and the squared norm of the ray vector (the sky
    direction's, before torch.sqrt). A: 24 float32 (_at); M: 12 float32, rows 0..2 of
    world_to_camera^-1."""
    n0, n1, n2, v0, v1, v2 = _ray(nx, ny, A)
    return _surface_ray(n0, n1, n2, v0, v1, v2, d, M)


@njit(**INLINE)
def _wclamp(wv):
    return TINY if abs(wv) < TINY else wv


@njit(cache=True)
def ray_tables(px, py, kx, ky, A):
    """The rays of a sample grid (px (1, w): one row of x for all rows, py (h, 1): one y
    per row) for a projection whose inverse keeps x and y apart (the perspective and
    off-axis ones: A's cross terms and the w row's x, y terms are +-0, its z and w
    constants are not 0): then _ray's near point and vector are n0, v0 per column, n1, v1
    per row and n2, v2 constant, bit for bit (a term +-0 added to a non-zero value leaves
    it as it is; columns or rows whose product is 0, where the zero's sign would count,
    send every pixel the general way). Returns (ok, CN0, CV0 (w,), RN1, RV1 (h,), K (2,):
    n2, v2); ok false: use _ray per pixel."""
    w = px.shape[1]
    h = py.shape[0]
    CN0 = np.empty(w, dtype=np.float32)
    CV0 = np.empty(w, dtype=np.float32)
    RN1 = np.empty(h, dtype=np.float32)
    RV1 = np.empty(h, dtype=np.float32)
    K = np.empty(2, dtype=np.float32)
    ok = (px.shape[0] == 1) & (py.shape[1] == 1)
    for i in range(24):
        ok &= abs(A[i]) < INF
    for k in (0, 12):
        ok &= ((A[k + 1] == ZERO) & (A[k + 3] == ZERO) & (A[k + 6] == ZERO)
               & (A[k + 7] == ZERO) & (A[k + 9] == ZERO) & (A[k + 10] == ZERO)
               & (A[k + 8] != ZERO) & (A[k + 11] != ZERO))
    if not ok:
        return False, CN0, CV0, RN1, RV1, K
    wn = _wclamp(A[11])
    wf = _wclamp(A[23])
    for x in range(w):
        nx = px[0, x] * kx - ONE
        t = nx * A[0]
        u = nx * A[12]
        ok &= (abs(nx) < INF) & (t != ZERO) & (u != ZERO)
        n0 = (t + A[2]) / wn
        CN0[x] = n0
        CV0[x] = (u + A[14]) / wf - n0
    for y in range(h):
        ny = ONE - py[y, 0] * ky
        t = ny * A[4]
        u = ny * A[16]
        ok &= (abs(ny) < INF) & (t != ZERO) & (u != ZERO)
        n1 = (t + A[5]) / wn
        RN1[y] = n1
        RV1[y] = (u + A[17]) / wf - n1
    n2 = A[8] / wn
    K[0] = n2
    K[1] = A[20] / wf - n2
    return ok, CN0, CV0, RN1, RV1, K


@njit(**INLINE)
def _sky_ray(v0, v1, v2, nrm, M):
    """_sky_px of the ray vector v."""
    nrm = TINY if nrm < TINY else nrm  # clamp_min (NaN stays NaN)
    r0 = v0 / nrm
    r1 = v1 / nrm
    r2 = v2 / nrm
    o0 = ((ZERO + M[0] * r0) + M[1] * r1) + M[2] * r2
    o1 = ((ZERO + M[4] * r0) + M[5] * r1) + M[6] * r2
    o2 = ((ZERO + M[8] * r0) + M[9] * r1) + M[10] * r2
    return _nan0(o0), _nan0(o1), _nan0(o2)


@njit(**INLINE)
def _sky_px(nx, ny, nrm, A, M):
    """The sky direction of one pixel, nrm = torch.sqrt of _surface_px's squared norm."""
    _, _, _, v0, v1, v2 = _ray(nx, ny, A)
    return _sky_ray(v0, v1, v2, nrm, M)


@njit(**INLINE)
def _ndc_span(px, py, y, kx, ky, xa, nxr, nyr):
    """NDC coordinates of row y's samples xa .. xa + len(nxr) - 1 into nxr, nyr: px (h, w)
    or (1, w) (one row for all), py (h, w) or (h, 1) (one value per row); kx, ky float32
    2 / W, 2 / H."""
    m = nxr.shape[0]
    pxr = px[0] if px.shape[0] == 1 else px[y]
    for i in range(m):
        nxr[i] = pxr[xa + i] * kx - ONE
    if py.shape[1] == 1:
        c = ONE - py[y, 0] * ky
        for i in range(m):
            nyr[i] = c
    else:
        pyr = py[y]
        for i in range(m):
            nyr[i] = ONE - pyr[xa + i] * ky


@njit(**INLINE)
def _ndc_row(px, py, y, kx, ky, nxr, nyr):
    """_ndc_span of the whole row y (nxr, nyr of the row's length)."""
    _ndc_span(px, py, y, kx, ky, 0, nxr, nyr)


@njit(**INLINE)
def _unproject_row(px, py, y, kx, ky, dr, A, M, o0, o1, o2, o3, sr, RT):
    """unproject_kernel's row y (samples as _ndc_row, depths dr) into the rows o0 .. o3
    and sr (the squared norms; the frame's rows or row buffers); returns its sky pixels'
    count (counted in a loop of its own: a reduction in the pixel loop stops it
    vectorising). RT: ray_tables(px, py, kx, ky, A) (when it holds, the rays come from it:
    6 of a pixel's 7 divisions gone; the two loops are written out, as in _reproject_run,
    so that each reads its rays as plain loads or scalars and vectorises). Inlined by the
    kernels that unproject a row (unproject_kernel, reproject_kernel, gffe.hist_p_kernel)."""
    w = dr.shape[0]
    ok, CN0, CV0, RN1, RV1, K = RT
    if ok:
        n1 = RN1[y]
        v1 = RV1[y]
        n2 = K[0]
        v2 = K[1]
        for x in range(w):
            a, b, c, e, s = _surface_ray(CN0[x], n1, n2, CV0[x], v1, v2, dr[x], M)
            o0[x] = a
            o1[x] = b
            o2[x] = c
            o3[x] = e
            sr[x] = s
    else:
        nxr = np.empty(w, dtype=np.float32)
        nyr = np.empty(w, dtype=np.float32)
        _ndc_row(px, py, y, kx, ky, nxr, nyr)
        for x in range(w):
            a, b, c, e, s = _surface_px(nxr[x], nyr[x], dr[x], A, M)
            o0[x] = a
            o1[x] = b
            o2[x] = c
            o3[x] = e
            sr[x] = s
    n = 0
    for x in range(w):
        n += np.int64(dr[x] == INF)
    return n


@njit(**KERNEL)
def unproject_kernel(depth, px, py, kx, ky, A, M, out, ss, nsky):
    """fgcli.ops.gffe.unproject but the sky: depth (h, w), samples as _ndc_row, out
    (4, h, w); ss (h, w) the squared norms, nsky (h,) int64 the sky pixels per row."""
    h, w = depth.shape
    RT = ray_tables(px, py, kx, ky, A)
    for y in prange(h):
        nsky[y] = _unproject_row(px, py, y, kx, ky, depth[y], A, M, out[0, y], out[1, y],
                                 out[2, y], out[3, y], ss[y], RT)


@njit(**INLINE)
def _sky_span(dr, nxr, nyr, nr, xa, n, A, M, t0, t1, t2, RT, y):
    """The sky passes' span of n pixels from column xa of row y: its sky pixels (depth row
    dr) are counted, and when there are any the directions of all n (_sky_px, nr their
    norms; the rays from RT = ray_tables(...) where it holds, else from nxr, nyr) go to
    t0, t1, t2 for the caller's merge. Returns the count (0: the span is skipped)."""
    m = 0
    for i in range(n):
        m += np.int64(dr[xa + i] == INF)
    if m != 0:
        ok, _, CV0, _, RV1, K = RT
        if ok:
            v1 = RV1[y]
            v2 = K[1]
            for i in range(n):
                a, b, c = _sky_ray(CV0[xa + i], v1, v2, nr[xa + i], M)
                t0[i] = a
                t1[i] = b
                t2[i] = c
        else:
            for i in range(n):
                a, b, c = _sky_px(nxr[xa + i], nyr[xa + i], nr[xa + i], A, M)
                t0[i] = a
                t1[i] = b
                t2[i] = c
    return m


@njit(**INLINE)
def copy_row_planes(p, older, y):
    """Row y of the four planes p (4, h, w) into every plane set of older (j, 4, h, w)."""
    for j in range(older.shape[0]):
        for c in range(4):
            pc = p[c, y]
            qc = older[j, c, y]
            for x in range(pc.shape[0]):
                qc[x] = pc[x]


@njit(**KERNEL)
def unproject_sky_kernel(depth, px, py, kx, ky, A, M, nrm, y0, out, older):
    """unproject_kernel's second pass: the sky pixels of rows y0 .. y0 + len(nrm) - 1, nrm
    their rows of torch.sqrt(ss). older (j, 4, h, w), or (0, 4, 1, 1) for none: each row
    of out finished here is copied into every plane of older while it is in cache
    (gffe's trajectory planes: 1.1 ms for torch's copy of blade's 508 sky rows after the
    pass)."""
    w = depth.shape[1]
    RT = ray_tables(px, py, kx, ky, A)
    for r in prange(nrm.shape[0]):
        y = y0 + r
        nxr = np.empty(w, dtype=np.float32)
        nyr = np.empty(w, dtype=np.float32)
        if not RT[0]:  # (the per-pixel rays' samples; with the tables none are read)
            _ndc_row(px, py, y, kx, ky, nxr, nyr)
        nr = nrm[r]
        # directions into span buffers, then merged: the merge in the same loop (reading
        # and writing out) stops it vectorising (3x slower); spans without sky are skipped
        t0 = np.empty(SKY_SPAN, dtype=np.float32)
        t1 = np.empty(SKY_SPAN, dtype=np.float32)
        t2 = np.empty(SKY_SPAN, dtype=np.float32)
        dr = depth[y]
        o0 = out[0, y]
        o1 = out[1, y]
        o2 = out[2, y]
        for xs in range((w + SKY_SPAN - 1) // SKY_SPAN):
            xa = np.int64(xs) * SKY_SPAN
            n = min(SKY_SPAN, w - xa)
            if _sky_span(dr, nxr, nyr, nr, xa, n, A, M, t0, t1, t2, RT, y) == 0:
                continue
            for i in range(n):
                sky = dr[xa + i] == INF
                o0[xa + i] = t0[i] if sky else o0[xa + i]
                o1[xa + i] = t1[i] if sky else o1[xa + i]
                o2[xa + i] = t2[i] if sky else o2[xa + i]
        copy_row_planes(out, older, y)


# ----------------------------------------------------------------------------- project

@njit(**INLINE)
def _project_px(x0, x1, x2, x3, V, P, hw, hh):
    """(px, py, depth, ok) of one homogeneous position: V (4 float32) row 2 of
    world_to_camera, P (12 float32) rows 0, 1, 3 of projection @ world_to_camera; hw, hh =
    0.5 W, 0.5 H."""
    vz = (((ZERO + V[0] * x0) + V[1] * x1) + V[2] * x2) + V[3] * x3
    c0 = (((ZERO + P[0] * x0) + P[1] * x1) + P[2] * x2) + P[3] * x3
    c1 = (((ZERO + P[4] * x0) + P[5] * x1) + P[6] * x2) + P[7] * x3
    cw = (((ZERO + P[8] * x0) + P[9] * x1) + P[10] * x2) + P[11] * x3
    ok = (cw > EPS_W) & (vz < ZERO) & ((x3 != ZERO) | (x0 != ZERO) | (x1 != ZERO) |
                                       (x2 != ZERO))
    safe = cw if ok else ONE
    qx = (c0 / safe + ONE) * hw
    qy = (ONE - c1 / safe) * hh
    # |q| < OFF is false for NaN and +-inf: also torch's isfinite test
    ok = ok & (abs(qx) < OFF) & (abs(qy) < OFF)
    # where ok, vz < 0: -vz > 0 or +inf (nan_to_num and clamp_min(0) change nothing)
    dep = -vz if x3 > ZERO else INF
    return (qx if ok else OFF), (qy if ok else OFF), (dep if ok else INF), ok


@njit(**KERNEL)
def project_kernel(X, V, P, hw, hh, px, py, depth, ok):
    """fgcli.ops.gffe.project on rows: X (4, h, w); outputs (h, w)."""
    h, w = X.shape[1], X.shape[2]
    for y in prange(h):
        a0 = X[0, y]
        a1 = X[1, y]
        a2 = X[2, y]
        a3 = X[3, y]
        rx = px[y]
        ry = py[y]
        rd = depth[y]
        ro = ok[y]
        for x in range(w):
            qx, qy, d, o = _project_px(a0[x], a1[x], a2[x], a3[x], V, P, hw, hh)
            rx[x] = qx
            ry[x] = qy
            rd[x] = d
            ro[x] = o


# ----------------------------------------------------------------------------- reproject

@njit(**INLINE)
def _reproject_run(px, py, y, kx, ky, dr, A, M, V, P, hw, hh, xa, xb, rx, ry, rd, ro, sr,
                   nxb, nyb, RT):
    """reproject_kernel's pixels xa..xb of row y alone (no valid mask): the samples by
    _ndc_span (into nxb, nyb), unprojected (_surface_px) and projected in one
    loop (the rays from RT = ray_tables(...) where it holds), the sky counted in a loop of
    its own (as _unproject_row: each loop vectorised); returns the run's sky count (its
    squared norms in sr)."""
    m = xb - xa
    ok, CN0, CV0, RN1, RV1, K = RT
    if ok:
        n1 = RN1[y]
        v1 = RV1[y]
        n2 = K[0]
        v2 = K[1]
        for i in range(m):
            a, b, c, e, q = _surface_ray(CN0[xa + i], n1, n2, CV0[xa + i], v1, v2,
                                         dr[xa + i], M)
            sr[xa + i] = q
            qx, qy, dd, o = _project_px(a, b, c, e, V, P, hw, hh)
            rx[xa + i] = qx
            ry[xa + i] = qy
            rd[xa + i] = dd
            ro[xa + i] = o
    else:
        _ndc_span(px, py, y, kx, ky, xa, nxb[:m], nyb[:m])
        for i in range(m):
            a, b, c, e, q = _surface_px(nxb[i], nyb[i], dr[xa + i], A, M)
            sr[xa + i] = q
            qx, qy, dd, o = _project_px(a, b, c, e, V, P, hw, hh)
            rx[xa + i] = qx
            ry[xa + i] = qy
            rd[xa + i] = dd
            ro[xa + i] = o
    n = 0
    for i in range(m):
        n += np.int64(dr[xa + i] == INF)
    return n


@njit(**KERNEL)
def reproject_kernel(depth, px, py, kx, ky, A, M, V, P, hw, hh, opx, opy, od, ook, ss, nsky,
                     rows, some, run, vrun, valid, has_valid, dm):
    """project(unproject(depth, samples), camera 2) without the positions in memory: per
    row, unproject_kernel's surface points into row buffers, then project_kernel's loop
    on them (each loop as vectorised as in its own kernel; the positions stay in cache).
    ss, nsky as unproject_kernel's; the sky pixels' outputs are finished by
    reproject_sky_kernel. With ``some``, only the rows y with rows[y] != 0 (uint8 (h,));
    the others get a sky count of 0 (the sky pass skips it) and garbage outputs. With
    ``some`` and run < w (no valid mask then: has_valid false), only the runs of ``run``
    pixels of those rows (pixels r * run .. (r + 1) * run - 1) that hold a 0 in vrun (h,
    w) uint8 0 / 1 (fill_holes: its holes), one by one (_reproject_run); the others'
    outputs are garbage and their ss 1 (the sky pass's sqrt reads no garbage).

    has_valid: the depth is where(valid, depth, 0) (valid (h, w) uint8; a layer's valid
    cells) and ook is ok & valid, without that depth plane made first: each row masked
    into a row buffer, and written to dm (h, w) where the row has sky (the sky pass reads
    dm then, on those rows only)."""
    h, w = depth.shape
    nr = (w + run - 1) // run
    RT = ray_tables(px, py, kx, ky, A)
    for y in prange(h):
        if some and rows[y] == U0:
            nsky[y] = 0  # (the sky pass skips it)
            continue
        if some and run < w:
            sr = ss[y]
            vr = vrun[y]
            nxb = np.empty(run, dtype=np.float32)
            nyb = np.empty(run, dtype=np.float32)
            n = 0
            for r in range(nr):
                xa = np.int64(r) * run
                xb = min(xa + run, w)
                m = np.uint8(1)
                for x in range(xa, xb):
                    m = min(m, vr[x])
                if m != U0:
                    for x in range(xa, xb):
                        sr[x] = ONE
                    continue
                n += _reproject_run(px, py, y, kx, ky, depth[y], A, M, V, P, hw, hh, xa, xb,
                                    opx[y], opy[y], od[y], ook[y], sr, nxb, nyb, RT)
            nsky[y] = n
            continue
        dr = depth[y]
        vb = np.empty(w, dtype=np.uint8)  # (a row buffer either way: no branch per pixel)
        if has_valid:
            for x in range(w):
                vb[x] = valid[y, x]
        else:
            for x in range(w):
                vb[x] = np.uint8(1)
        db = np.empty(w, dtype=np.float32)
        for x in range(w):
            db[x] = dr[x] if vb[x] != U0 else ZERO
        o0 = np.empty(w, dtype=np.float32)
        o1 = np.empty(w, dtype=np.float32)
        o2 = np.empty(w, dtype=np.float32)
        o3 = np.empty(w, dtype=np.float32)
        n = _unproject_row(px, py, y, kx, ky, db, A, M, o0, o1, o2, o3, ss[y], RT)
        nsky[y] = n
        if has_valid and n > 0:
            for x in range(w):
                dm[y, x] = db[x]
        rx = opx[y]
        ry = opy[y]
        rd = od[y]
        ro = ook[y]
        for x in range(w):
            qx, qy, d, o = _project_px(o0[x], o1[x], o2[x], o3[x], V, P, hw, hh)
            rx[x] = qx
            ry[x] = qy
            rd[x] = d
            ro[x] = o & (vb[x] != U0)


@njit(**KERNEL)
def reproject_sky_kernel(depth, px, py, kx, ky, A, M, V, P, hw, hh, nrm, y0, opx, opy, od,
                         ook, nsky):
    """reproject_kernel's sky pixels on rows y0 .. y0 + len(nrm) - 1 (nrm: torch.sqrt of
    their squared norms): the direction (unproject_sky_kernel's), projected. Rows without
    sky (nsky, its counts; 0 for the rows it skipped) are not read."""
    w = depth.shape[1]
    RT = ray_tables(px, py, kx, ky, A)
    for r in prange(nrm.shape[0]):
        y = y0 + r
        if nsky[y] == 0:
            continue
        nxr = np.empty(w, dtype=np.float32)
        nyr = np.empty(w, dtype=np.float32)
        if not RT[0]:  # (the per-pixel rays' samples; with the tables none are read)
            _ndc_row(px, py, y, kx, ky, nxr, nyr)
        nr = nrm[r]
        t0 = np.empty(SKY_SPAN, dtype=np.float32)
        t1 = np.empty(SKY_SPAN, dtype=np.float32)
        t2 = np.empty(SKY_SPAN, dtype=np.float32)
        dr = depth[y]
        rx = opx[y]
        ry = opy[y]
        rd = od[y]
        ro = ook[y]
        for xs in range((w + SKY_SPAN - 1) // SKY_SPAN):  # (spans without sky skipped)
            xa = np.int64(xs) * SKY_SPAN
            n = min(SKY_SPAN, w - xa)
            if _sky_span(dr, nxr, nyr, nr, xa, n, A, M, t0, t1, t2, RT, y) == 0:
                continue
            for i in range(n):
                sky = dr[xa + i] == INF
                qx, qy, d, o = _project_px(t0[i], t1[i], t2[i], ZERO, V, P, hw, hh)
                rx[xa + i] = qx if sky else rx[xa + i]
                ry[xa + i] = qy if sky else ry[xa + i]
                rd[xa + i] = d if sky else rd[xa + i]
                ro[xa + i] = o if sky else ro[xa + i]
