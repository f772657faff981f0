"""GFFE's per-pixel steps (fgcli.ops.gffe) beyond the camera geometry (fgcli.kernels.geom):
the glue of the ops (their torch.where / gather chains) fused into a few passes, the
nearest-depth-wins splat of the background layers, the far-biased push-pull pyramid. The
same float32 operations in the same order as the torch ops (every product and sum rounded
on its own; Python scalars rounded to float32 as torch rounds them), so the results are
bit-identical. What torch computes with MKL / Sleef (log, sqrt) stays in torch
(fgcli.kernels.ops passes the results in).

Per-pixel bodies are selects, no branches; rows run in parallel (prange), the inner loop
over x is a plain range in the kernel body (fgcli.kernels.warp's notes). Masks come in
as uint8 views of the bool tensors: a select on an element of a bool array stopped LLVM
from vectorising the row loop (no gathers), a uint8 compare does not."""
from __future__ import annotations

import numpy as np
from numba import njit, prange

from fgcli.kernels._common import (ALL1, F32, I64_MAX, INF, INLINE, KERNEL, ROWS, clamp_b,
                                   f2i64, lut_row, sdepth_b, sflow_b, smv_b, sval_b)
from fgcli.kernels.geom import (_project_px, _surface_px, _unproject_row, copy_row_planes,
                                ray_tables)
from fgcli.kernels._intrin import HAVE_WINDOW16, atomic_min_i64, bilinear16x3, mad32
from fgcli.kernels.warp import I32, _bil_pair, _flat_coords, bil_taps

# the colour samples' taps fetched 16 pixels at a time (fgcli.kernels._intrin.bilinear16x3,
# AVX-512; a module constant, so numba compiles only the branch this CPU runs)
WINDOW16 = HAVE_WINDOW16

OFF = np.float32(1.0e6)  # fgcli.ops.gffe.OFF
ZERO = np.float32(0.0)
ONE = np.float32(1.0)
HALF = np.float32(0.5)
U0 = np.uint8(0)
FMAX = np.float32(3.4028234663852886e38)


@njit(**INLINE)
def _div(n, w):
    """n // w for 0 <= n, 0 < w (n + w < 2**53) as a float64 division: n / w = q + r / w
    lies at least 1 / w below q + 1, more than float64's rounding error there ((q + 1) *
    2**-53), so the floor is exact. An int64 division does not vectorise (~10-30 ms per
    1080p pass)."""
    return np.int64(np.floor(np.float64(n) / np.float64(w)))


# ----------------------------------------------------------------------------- sampling

SPAN = 64  # sample_where_kernel's unit of skipping


@njit(**INLINE)
def _sample_px(img, flow, sel, base, has_base, gxn, gyy, kx, ky, hw, hh, wm1, hm1, w, h,
               hw32, out, x, y):
    """sample_where_kernel's colour at pixel (x, y), selects only; w, h, hw32 = h * w int32
    (the taps are fgcli.kernels.warp's pair loads)."""
    s = sel[y, x] != U0
    fx = sflow_b(flow[0, y, x])
    fy = sflow_b(flow[1, y, x])
    zero = (fx == ZERO) & (fy == ZERO)
    p, rs, xi, nw, ne, sw, se = _flat_coords(fx, fy, gxn[x], gyy, kx, ky, hw, hh, wm1, hm1,
                                             w, h)
    for k in range(3):
        r = _bil_pair(img, mad32(I32(k), hw32, p), rs, xi, nw, ne, sw, se)
        r = sval_b(img[k, y, x]) if zero else r
        b = base[k, y, x] if has_base else ZERO
        out[k, y, x] = r if s else b


@njit(**ROWS)
def _sample_where_rows(ya, yb, img, flow, sel, base, has_base, fbase, has_fbase, gxn, gyn, kx, ky,
                       out, fout, inplace, want_f, f_inplace, XA, XB, YA, YB, Z, WT, R):
    """sample_where_kernel's rows ya..yb (one chunk of its parallel loop)."""
    h, w = sel.shape
    hw = F32(w * 0.5)
    hh = F32(h * 0.5)
    wm1 = F32(w - 1)
    hm1 = F32(h - 1)
    w32 = I32(w)
    h32 = I32(h)
    hw32 = I32(h * w)
    for y in range(ya, yb):
        gyy = gyn[y]
        sr = sel[y]
        keep = False  # fout is flow and the whole row selected: nothing to write
        if want_f and f_inplace and not has_fbase:
            m = np.int64(0)
            for x in range(w):
                m += np.int64(sr[x])
            keep = m == w
        if want_f and not keep:  # (per plane, base or zero chosen outside the loop: a
            # load under a select of has_fbase made the loop scalar or masked)
            for c in range(2):
                fo = fout[c, y]
                fl = flow[c, y]
                if has_fbase:
                    fb = fbase[c, y]
                    for x in range(w):
                        fo[x] = fl[x] if sr[x] != U0 else fb[x]
                else:
                    for x in range(w):
                        fo[x] = fl[x] if sr[x] != U0 else ZERO
        for xs in range((w + SPAN - 1) // SPAN):
            xa = np.int64(xs) * SPAN
            n = min(SPAN, w - xa)
            m = np.int64(0)  # selected pixels in the run (sel is 0 / 1)
            sn = sr[xa:xa + n]
            for i in range(n):
                m += np.int64(sn[i])
            if m == 0:
                if not inplace:
                    for k in range(3):
                        ok = out[k, y, xa:xa + n]
                        if has_base:
                            bk = base[k, y, xa:xa + n]
                            for i in range(n):
                                ok[i] = bk[i]
                        else:
                            for i in range(n):
                                ok[i] = ZERO
            elif WINDOW16 and 2 * m >= n:  # mostly selected: the run's taps into row
                # buffers, 16 pixels per fetch, then the selects (a sparse run: per pixel)
                for i in range(n):
                    x = xa + i
                    bil_taps(sflow_b(flow[0, y, x]), sflow_b(flow[1, y, x]), x, gxn[x], gyy,
                             kx, ky, hw, hh, wm1, hm1, w32, h32, XA, XB, YA, YB, WT, Z)
                for blk in range(n // 16):
                    bilinear16x3(img, hw32, w32, h32, XA, XB, YA, YB, WT, Z,
                                 I32(xa + 16 * blk), I32(y * w), R, w32, I32(0))
                # the selects per plane through row views, base or zero chosen outside
                # the loop (per pixel, with base's load under has_base, the loop ran
                # scalar: three loads, three stores and two branches a pixel)
                nn = n // 16 * 16
                sv = sn[:nn]
                for k in range(3):
                    rk = R[k, xa:xa + nn]
                    ok = out[k, y, xa:xa + nn]
                    if has_base:
                        bk = base[k, y, xa:xa + nn]
                        for i in range(nn):
                            ok[i] = rk[i] if sv[i] != U0 else bk[i]
                    else:
                        for i in range(nn):
                            ok[i] = rk[i] if sv[i] != U0 else ZERO
                for i in range(n // 16 * 16, n):  # (a row's last w % 16 pixels)
                    _sample_px(img, flow, sel, base, has_base, gxn, gyy, kx, ky, hw, hh,
                               wm1, hm1, w32, h32, hw32, out, xa + i, y)
            else:
                for i in range(n):
                    _sample_px(img, flow, sel, base, has_base, gxn, gyy, kx, ky, hw, hh,
                               wm1, hm1, w32, h32, hw32, out, xa + i, y)


@njit(**KERNEL)
def sample_where_kernel(img, flow, sel, base, has_base, fbase, has_fbase, gxn, gyn, kx, ky,
                        out, fout, inplace, want_f, f_inplace):
    """out = where(sel, backward_warp(img, flow, 'bilinear'), base or 0) (3 channels) and,
    with want_f, fout = where(sel, flow, fbase or 0); f_inplace: fout is flow itself (a
    row wholly selected is then left as it is: the warp's dense selection, 16 MB of
    writes spared per 1080p frame).

    Sparse selections (the fills select their holes, often 0-2 % of the pixels) skip the
    sampling: a run of SPAN pixels with no pixel selected copies base (or zeroes; nothing
    when ``inplace``: out is base itself); any other run computes every pixel with
    selects (with AVX-512 or AVX2, a run at least half selected fetches its taps 16 pixels
    at a time: fgcli.kernels._intrin.bilinear16x3). The flow outside the selection is never
    read in a skipped run (the fills leave it unwritten; a sampled run sanitises it)."""
    h, w = sel.shape
    nch = min(h, 64)
    for ch in prange(nch):
        ya = np.int64(ch) * h // nch
        yb = (np.int64(ch) + 1) * h // nch
        # (row buffers of bil_taps and bilinear16x3, one set per chunk of rows; used with
        # the window fetches only)
        XA = np.empty(w, dtype=np.int32)
        XB = np.empty(w, dtype=np.int32)
        YA = np.empty(w, dtype=np.int32)
        YB = np.empty(w, dtype=np.int32)
        Z = np.empty(w, dtype=np.int32)
        WT = np.empty((4, w), dtype=np.float32)
        R = np.empty((3, w), dtype=np.float32)
        _sample_where_rows(ya, yb, img, flow, sel, base, has_base, fbase, has_fbase, gxn, gyn, kx,
                           ky, out, fout, inplace, want_f, f_inplace, XA, XB, YA, YB, Z, WT, R)


# ----------------------------------------------------------------------------- warp

@njit(**INLINE)
def _offset_px(X, V, P, hw, hh, out, dn, x, y, yh, rest):
    """offsets_kernel at pixel x of row y; rest: the position is at its origin."""
    qx, qy, d, o = _project_px(X[0, y, x], X[1, y, x], X[2, y, x], X[3, y, x], V, P, hw, hh)
    dx = ZERO if rest else qx - (F32(I32(x)) + HALF)
    dy = ZERO if rest else qy - yh
    out[0, y, x] = -(dx if o else OFF)
    out[1, y, x] = -(dy if o else OFF)
    dn[0, y, x] = d


@njit(**KERNEL)
def offsets_kernel(X, V, P, hw, hh, out, dn, O, has_o):
    """warp_positions' projection and splat vectors in one pass: project_kernel's (px, py,
    depth, ok) of the positions X (4, h, w) (V, P, hw, hh its coefficients), then out =
    -stack([where(ok, px - xh, OFF), where(ok, py - yh, OFF)]) and dn = the depth (the
    projected coordinates and flags never written: ~2 ms per 1080p frame). has_o: where
    X equals the origin O (4, h, w) in all four planes, px - xh and py - yh are zero
    (else O is not read: a stand-in of X's shape)."""
    h, w = X.shape[1], X.shape[2]
    for pr in prange(h):
        y = np.int64(pr)
        yh = F32(y) + HALF
        if has_o:  # (two loops: loads under a runtime flag can keep a loop scalar, _eq1_row)
            for x in range(w):
                rest = ((X[0, y, x] == O[0, y, x]) & (X[1, y, x] == O[1, y, x]) &
                        (X[2, y, x] == O[2, y, x]) & (X[3, y, x] == O[3, y, x]))
                _offset_px(X, V, P, hw, hh, out, dn, x, y, yh, rest)
        else:
            for x in range(w):
                _offset_px(X, V, P, hw, hh, out, dn, x, y, yh, False)


# ----------------------------------------------------------------------------- dilation

@njit(**KERNEL)
def dilate_traj_kernel(traj, src, dyn, has_dyn, pd, out):
    """dilate_trajectory after the nearest-depth dilation: src (2, H, W) the winner's pixel
    centre (dilate_nearest_depth of the centre coordinates), pd (4, H, W) the winner's
    depth unprojected on each pixel's ray; out (k, 4, H, W)."""
    k = traj.shape[0]
    h, w = src.shape[1:]
    hm1 = F32(h - 1)
    wm1 = F32(w - 1)
    wf = F32(w)
    for pr in prange(h):
        y = np.int64(pr)
        nidx = np.empty(w, dtype=np.int64)
        both = np.empty(w, dtype=np.float32)
        for x in range(w):
            fi = clamp_b(np.floor(src[1, y, x]), ZERO, hm1) * wf + \
                clamp_b(np.floor(src[0, y, x]), ZERO, wm1)
            n = np.int64(fi)
            ny = n // w
            nx = n - ny * w
            nidx[x] = n
            t3 = traj[0, 3, ny, nx]
            b = (t3 > ZERO) & (traj[0, 3, y, x] > ZERO)
            # (without ``dynamic``, dyn is a same-shape stand-in: reads stay in bounds)
            dn = (dyn[ny, nx] != U0) | (not has_dyn)
            dx = (dyn[y, x] != U0) & has_dyn
            b = b & dn & (not dx)
            both[x] = ONE if b else ZERO
            take = b & (pd[3, y, x] > ZERO)
            for c in range(4):
                out[0, c, y, x] = pd[c, y, x] if take else traj[0, c, y, x]
        for i in range(1, k):
            for x in range(w):
                n = nidx[x]
                ny = n // w
                nx = n - ny * w
                ok = (both[x] != ZERO) & (traj[i, 3, ny, nx] == traj[0, 3, ny, nx])
                for c in range(4):
                    v = out[0, c, y, x] - (traj[0, c, ny, nx] - traj[i, c, ny, nx])
                    out[i, c, y, x] = v if ok else traj[i, c, y, x]


@njit(**KERNEL)
def dilate_pos_kernel(traj, src, dyn, has_dyn, pd, a, quad, cq, out):
    """estimate_positions(dilate_trajectory(...)) without the dilated trajectory: P_0' as
    dilate_traj_kernel's, P_1' (and P_2' when quad) per pixel, then Eq. 1 (a: alpha;
    quad: + cq * (P_0' - 2 P_1' + P_2')) where the kinds agree, else P_0'; out (4, H, W)."""
    h, w = src.shape[1:]
    hm1 = F32(h - 1)
    wm1 = F32(w - 1)
    wf = F32(w)
    i2 = 2 if quad else 1  # (k = 2: a plane that exists, unused)
    two = F32(2.0)
    # the winner's flat index n reads flat views: the element [n // w, n % w], no division
    tf = traj.reshape((traj.shape[0], 4, h * w))
    df = dyn.reshape(h * w)
    for pr in prange(h):
        y = np.int64(pr)
        nidx = np.empty(w, dtype=np.int64)
        both = np.empty(w, dtype=np.float32)
        for x in range(w):
            fi = clamp_b(np.floor(src[1, y, x]), ZERO, hm1) * wf + \
                clamp_b(np.floor(src[0, y, x]), ZERO, wm1)
            n = np.int64(fi)
            nidx[x] = n
            t3 = tf[0, 3, n]
            b = (t3 > ZERO) & (traj[0, 3, y, x] > ZERO)
            dn = (df[n] != U0) | (not has_dyn)
            dx = (dyn[y, x] != U0) & has_dyn
            b = b & dn & (not dx)
            both[x] = ONE if b else ZERO
            take = b & (pd[3, y, x] > ZERO)
            for c in range(4):
                out[c, y, x] = pd[c, y, x] if take else traj[0, c, y, x]
        for x in range(w):
            n = nidx[x]
            b = both[x] != ZERO
            t03 = tf[0, 3, n]
            ok1 = b & (tf[1, 3, n] == t03)
            ok2 = b & (tf[i2, 3, n] == t03)
            p03 = out[3, y, x]
            q13 = (p03 - (t03 - tf[1, 3, n])) if ok1 else traj[1, 3, y, x]
            q23 = (p03 - (t03 - tf[i2, 3, n])) if ok2 else traj[i2, 3, y, x]
            same = (q13 == p03) & ((q23 == p03) | (not quad))
            for c in range(3):
                p0c = out[c, y, x]
                q1 = (p0c - (tf[0, c, n] - tf[1, c, n])) if ok1 else traj[1, c, y, x]
                q2 = (p0c - (tf[0, c, n] - tf[i2, c, n])) if ok2 else traj[i2, c, y, x]
                r = p0c + a * (p0c - q1)
                rq = r + cq * ((p0c - two * q1) + q2)
                r = rq if quad else r
                out[c, y, x] = r if same else p0c


DYN_SPAN = 32  # dilate_dyn_pos_kernel's unit of skipping


@njit(**INLINE)
def _eq1(p0c, q1, q2, a, quad, cq, same):
    """Eq. 1 of one coordinate (+ the quadratic term when quad), P_0 where the kinds
    differ: estimate_positions' arithmetic."""
    r = p0c + a * (p0c - q1)
    rq = r + cq * ((p0c - F32(2.0) * q1) + q2)
    r = rq if quad else r
    return r if same else p0c


@njit(**KERNEL)
def dilate_dyn_pos_kernel(traj, depth, dyn, gx, gy, kx, ky, A, M, a, quad, cq, out):
    """dilate_pos_kernel for dilate=dynamic, the dilation and its unprojection computed
    here where they can matter. A pixel moves with its 3x3 nearest-depth winner only when
    it is static and the winner dynamic, so every pixel first takes Eq. 1 of its own
    trajectory (one vectorised pass per row), and in spans of DYN_SPAN pixels whose 3x3
    neighbourhood holds a dynamic pixel each static pixel then finds its winner as
    dilate3_kernel does (sanitised depths, +inf outside, taps in row-major order, the
    centre keeps ties) and, where that winner is dynamic, takes its depth on its own ray
    as unproject_kernel does (_surface_px: w = 0 for the sky, which is never taken, so no
    sky pass) and moves as the winner moves (dilate_pos_kernel's P_0', P_1', P_2').
    depth (h, w) frame 1's; gx (1, w), gy (h, 1) the pixel centres; kx, ky, A, M
    unproject_kernel's coefficients."""
    h, w = depth.shape
    i2 = 2 if quad else 1  # (k = 2: a plane that exists, unused)
    tf = traj.reshape((traj.shape[0], 4, h * w))
    df = dyn.reshape(h * w)
    for pr in prange(h):
        y = np.int64(pr)
        for x in range(w):
            p03 = traj[0, 3, y, x]
            same = (traj[1, 3, y, x] == p03) & ((traj[i2, 3, y, x] == p03) | (not quad))
            for c in range(3):
                out[c, y, x] = _eq1(traj[0, c, y, x], traj[1, c, y, x], traj[i2, c, y, x],
                                    a, quad, cq, same)
            out[3, y, x] = p03
        ya = max(y - 1, 0)
        yb = min(y + 2, h)
        ny = ONE - gy[y, 0] * ky
        for xs in range((w + DYN_SPAN - 1) // DYN_SPAN):
            xa = np.int64(xs) * DYN_SPAN
            xb = min(xa + DYN_SPAN, w)
            m = U0
            for yy in range(ya, yb):
                for xx in range(max(xa - 1, 0), min(xb + 1, w)):
                    m |= dyn[yy, xx]
            if m == U0:
                continue
            for x in range(xa, xb):
                if dyn[y, x] != U0 or not traj[0, 3, y, x] > ZERO:
                    continue
                b = INF
                c = np.int64(4)
                for j in range(9):
                    yy = y + j // 3 - 1
                    xx = x + j % 3 - 1
                    if yy >= 0 and yy < h and xx >= 0 and xx < w:
                        d = sdepth_b(depth[yy, xx])
                        if d < b:
                            b = d
                            c = np.int64(j)
                dc = sdepth_b(depth[y, x])
                if not b < dc:  # the centre keeps ties: it is its own winner (static)
                    continue
                n = (y + c // 3 - 1) * w + x + c % 3 - 1
                t03 = tf[0, 3, n]
                if df[n] == U0 or not t03 > ZERO:
                    continue
                nx = gx[0, x] * kx - ONE
                s0, s1, s2, s3, _ = _surface_px(nx, ny, b, A, M)
                if s3 > ZERO:
                    out[0, y, x] = s0
                    out[1, y, x] = s1
                    out[2, y, x] = s2
                    out[3, y, x] = s3
                else:
                    for cc in range(4):
                        out[cc, y, x] = traj[0, cc, y, x]
                ok1 = tf[1, 3, n] == t03
                ok2 = tf[i2, 3, n] == t03
                p03 = out[3, y, x]
                q13 = (p03 - (t03 - tf[1, 3, n])) if ok1 else traj[1, 3, y, x]
                q23 = (p03 - (t03 - tf[i2, 3, n])) if ok2 else traj[i2, 3, y, x]
                same = (q13 == p03) & ((q23 == p03) | (not quad))
                for cc in range(3):
                    p0c = out[cc, y, x]
                    q1 = (p0c - (tf[0, cc, n] - tf[1, cc, n])) if ok1 else traj[1, cc, y, x]
                    q2 = (p0c - (tf[0, cc, n] - tf[i2, cc, n])) if ok2 else traj[i2, cc, y, x]
                    out[cc, y, x] = _eq1(p0c, q1, q2, a, quad, cq, same)


# ----------------------------------------------------------------------------- background

@njit(**INLINE)
def _min_target(px, py, sc, use, wf, hf, wm1, hm1):
    """_splat_min's target cell of a fragment: (whether it is used and lands on the grid,
    the cell's flat index (int64, clamped))."""
    tx = np.floor(px / sc)
    ty = np.floor(py / sc)
    inside = (use != U0) & (tx >= ZERO) & (tx < wf) & (ty >= ZERO) & (ty < hf)
    return inside, f2i64(clamp_b(ty, ZERO, hm1) * wf + clamp_b(tx, ZERO, wm1))


@njit(**INLINE)
def _min_key(d, i):
    """_splat_min's key of a fragment of depth d and flat index i: the float32 bits of
    nan_to_num(d, nan=inf).clamp_min(0) << 32 | i."""
    d = INF if d != d else d
    d = ZERO if d < ZERO else d  # clamp_min(0) (-inf too)
    return (np.int64(np.float32(d).view(np.int32)) << 32) | i


@njit(**KERNEL)
def splat_min_kernel(px, py, sc, dn, use, h, w, want, has_want, buf, src, dep):
    """_splat_min of fragments (any grid) at target cells (floor(px / sc), floor(py / sc))
    of an (h, w) grid: buf (h * w) int64 scratch; src (h, w) int64 winning flat source
    index or -1, dep (h, w) its depth (+inf empty). Keys as the reference packs them:
    float32 bits of nan_to_num(dn, nan=inf).clamp_min(0) << 32 | source index.

    The scatter follows fgcli.kernels.splat.splat_kernel: where the fragment grid is the
    target grid, source rows are cut into bands, even bands run in parallel, then odd
    ones, and a fragment whose target row lies within half a band of its own band takes a
    plain read-compare-write; any other (and every fragment of another grid) an atomic
    minimum in a last pass. Unused fragments write nothing (the reference sends them to a
    dropped extra cell). The minimum is unique: the result never depends on timing.

    has_want: only target cells with want (h * w,) uint8 (0 / 1) set are splatted: src and
    dep are written on the rows that have a want cell only (the other cells of those rows
    come out empty; the rows without one are not written at all). For a caller that reads
    the result on those rows only (background_fill: its holes' spans of 64 pixels) it is
    the same there, and the scatter skips the rest; buf is then neither set nor read at
    the other cells (a 1080p frame's few holes: ~2 ms less, and ~1 ms per layer for the
    rows not written: 200-300 of 1080 rows have a hole on the benchmark). A fragment's
    want cell is read from a bitmap of want made here, 16 fragments per gather (h * w <
    2**31: the wrapper passes no want above)."""
    hs, ws = dn.shape
    hm1 = F32(h - 1)
    wm1 = F32(w - 1)
    wf = F32(w)
    hf = F32(h)
    for pr in prange(h):
        r = np.int64(pr) * w
        br = buf[r:r + w]  # (row views: see bits_count_kernel)
        if has_want:
            wr = want[r:r + w]
            nw = U0  # (a row without a want cell, most of them: one vectorised pass)
            for x in range(w):
                nw |= wr[x]
            if nw == U0:
                continue
            for x in range(w):
                if wr[x] != U0:
                    br[x] = I64_MAX
        else:
            for x in range(w):
                br[x] = I64_MAX
    same = (hs == h) & (ws == w)
    # with want: its cells as a bitmap (bit q & 31 of word q >> 5), read 16 fragments at a
    # time by gathers (lut_row): a fragment is tested against its target's want cell in the
    # vectorised pass, and the scatter sees the few that hit a want cell. (A uint8 read at
    # each fragment's target kept the pass scalar: 7 ms per 1080p frame for ~500 holes.)
    nwd = (h * w + 31) // 32 if has_want else 1
    bm = np.zeros(nwd, dtype=np.int32)
    if has_want:
        nfull = (h * w) // 32  # (whole words: a fixed inner loop, vectorised)
        for i in prange(nfull):
            acc = np.int32(0)
            for b in range(32):
                acc |= np.int32(want[32 * i + b] != U0) << np.int32(b)
            bm[i] = acc
        if nfull < nwd:
            acc = np.int32(0)
            for b in range(h * w - 32 * nfull):
                acc |= np.int32(want[32 * nfull + b] != U0) << np.int32(b)
            bm[nfull] = acc
    bh = max(8, (hs + 31) // 32)  # band height
    nband = (hs + bh - 1) // bh
    half = bh // 2
    # the deferred fragments of row y: targets and columns packed from y * ws on, ndef[y]
    # of them (a plane of targets written and read back whole cost ~1.3 ms per call)
    dq = np.empty(hs * ws, dtype=np.int64)
    dxs = np.empty(hs * ws, dtype=np.int32)
    ndef = np.zeros(hs, dtype=np.int64)
    for phase in range(2):
        for bi in prange((nband - phase + 1) // 2):
            band = 2 * np.int64(bi) + phase
            ya = band * bh
            yb = min(hs, ya + bh)
            zlo = (ya - half) * w
            zhi = (yb + half) * w
            qs = np.empty(ws, dtype=np.int64)
            ks = np.empty(ws, dtype=np.int64)
            Q = np.empty(ws, dtype=np.int32)  # (with want: targets, word indices, words,
            WI = np.empty(ws, dtype=np.int32)  # hit flags)
            WB = np.empty(ws, dtype=np.int32)
            HT = np.empty(ws, dtype=np.uint8)
            for y in range(ya, yb):
                r = y * ws
                nd = np.int64(0)
                if has_want:  # the few fragments that hit a want cell, found 8 at a time
                    for x in range(ws):
                        inside, q = _min_target(px[y, x], py[y, x], sc, use[y, x], wf, hf,
                                                wm1, hm1)
                        Q[x] = np.int32(q) if inside else np.int32(-1)
                        WI[x] = np.int32(q) >> np.int32(5)
                    lut_row(bm, WI, ws, WB)
                    anyh = U0
                    for x in range(ws):
                        q = Q[x]
                        hit = (q >= np.int32(0)) & (((WB[x] >> (q & np.int32(31))) &
                                                     np.int32(1)) != np.int32(0))
                        HT[x] = np.uint8(hit)
                        anyh |= HT[x]
                    if anyh != U0:
                        n8 = ws // 8
                        hv = HT[:n8 * 8].view(np.uint64)
                        for b in range(n8 + 1):  # (the last "word": the row's ws % 8)
                            if b < n8 and hv[b] == np.uint64(0):
                                continue
                            for x in range(8 * b, min(8 * b + 8, ws)):
                                if HT[x] == U0:
                                    continue
                                q = np.int64(Q[x])
                                if same & (q >= zlo) & (q < zhi):
                                    k = _min_key(dn[y, x], r + x)
                                    if k < buf[q]:
                                        buf[q] = k
                                else:
                                    dq[r + nd] = q
                                    dxs[r + nd] = np.int32(x)
                                    nd += 1
                    ndef[y] = nd
                    continue
                for x in range(ws):
                    inside, q = _min_target(px[y, x], py[y, x], sc, use[y, x], wf, hf,
                                            wm1, hm1)
                    qs[x] = q if inside else np.int64(-1)
                    ks[x] = _min_key(dn[y, x], r + x)
                for x in range(ws):
                    q = qs[x]
                    if q >= 0:
                        if same & (q >= zlo) & (q < zhi):
                            if ks[x] < buf[q]:
                                buf[q] = ks[x]
                        else:
                            dq[r + nd] = q
                            dxs[r + nd] = np.int32(x)
                            nd += 1
                ndef[y] = nd
    for pr in prange(hs):
        y = np.int64(pr)
        r = y * ws
        for j in range(ndef[y]):
            x = np.int64(dxs[r + j])
            atomic_min_i64(buf, dq[r + j], _min_key(dn[y, x], r + x))
    for pr in prange(h):
        y = np.int64(pr)
        br = buf[y * w:(y + 1) * w]  # (row views: see bits_count_kernel)
        if has_want:
            wr = want[y * w:(y + 1) * w]
            nw = U0
            for x in range(w):
                nw |= wr[x]
            if nw == U0:  # (a row without a want cell: left as it is)
                continue
            for x in range(w):
                src[y, x] = np.int64(-1)
                dep[y, x] = INF
            for x in range(w):
                if wr[x] != U0:
                    k = br[x]
                    if k != I64_MAX:
                        src[y, x] = k & np.int64(0xFFFFFFFF)
                        dep[y, x] = np.int32(k >> 32).view(np.float32)
            continue
        for x in range(w):
            k = br[x]
            hit = k != I64_MAX
            s = k & np.int64(0xFFFFFFFF)
            d = np.int32(k >> 32).view(np.float32)
            src[y, x] = s if hit else np.int64(-1)
            dep[y, x] = d if hit else INF


@njit(**KERNEL)
def bg_resolve_kernel(s0, d0, s1, d1, sc2, scf, hole, col0, col1, bil0, bil1, out_c, out_d,
                      out_m, filled, code):
    """project_background after the two splats: the nearer layer's fragment per hole
    (layer 1 on its own grid: pixel (y, x) reads cell (y // 2, x // 2) when sc2), its
    colour (nearest), depth and vector toward frame 1; code marks the pixels whose colour
    the bilinear pass replaces (1: layer 0's, 2: layer 1's; bil0 / bil1: that layer is
    read bilinearly)."""
    h, w = s0.shape
    w2 = s1.shape[1]
    inf_ = INF
    for pr in prange(h):
        y = np.int64(pr)
        yy = (y >> 1) if sc2 else y
        yh = F32(y) + HALF
        for x in range(w):
            xx = (np.int64(x) >> 1) if sc2 else np.int64(x)
            a = s0[y, x]
            da = d0[y, x]
            b = s1[yy, xx]
            db = d1[yy, xx]
            h0 = a >= 0
            h1 = b >= 0
            t1 = h1 & ((not h0) | (db < da))
            t0 = h0 & (not t1)
            ac = max(a, np.int64(0))
            bc = max(b, np.int64(0))
            ay = ac // w
            ax = ac - ay * w
            by = bc // w2
            bx = bc - by * w2
            f = (hole[y, x] != U0) & (t0 | t1)
            for k in range(3):
                c = col1[k, by, bx] if t1 else col0[k, ay, ax]
                out_c[k, y, x] = c if f else ZERO
            out_d[y, x] = (db if t1 else da) if f else inf_
            sx = ((F32(bx) + HALF) * scf) if t1 else (F32(ax) + HALF)
            sy = ((F32(by) + HALF) * scf) if t1 else (F32(ay) + HALF)
            mx = sx - (F32(I32(x)) + HALF)
            my = sy - yh
            out_m[0, y, x] = mx if f else ZERO
            out_m[1, y, x] = my if f else ZERO
            filled[y, x] = np.uint8(1) if f else U0
            c0 = np.uint8(1) if (f & t0 & bil0) else U0
            code[y, x] = np.uint8(2) if (f & t1 & bil1) else c0


KEEP3 = np.float32(1.0 - 1e-3)  # entering_surface's ``d1 * (1.0 - 1e-3)``


@njit(**INLINE)
def _nan_inf_b(v):
    """torch.nan_to_num(v, nan=inf): NaN -> +inf, +-inf -> +-float32 max."""
    r = FMAX if v == INF else v
    r = -FMAX if v == -INF else r
    return INF if v != v else r


@njit(**INLINE)
def _entering_px(mv1, depth1, depth1f, a, behind, entering, x, y, yh, wf, hf, wm1, hm1, w):
    """entering_surface's test at (x, y): 1 where the surface goes off-screen (or, behind,
    comes from behind a nearer one) and is nearer than ``dlim`` allows, else 0. depth1f:
    depth1's flat view (a flat pixel index reads it without a division)."""
    xh = F32(I32(x)) + HALF
    m0 = smv_b(mv1[0, y, x])
    m1 = smv_b(mv1[1, y, x])
    sx = xh + a * m0
    sy = yh + a * m1
    off = (sx < ZERO) | (sx >= wf) | (sy < ZERO) | (sy >= hf)
    dq = _nan_inf_b(depth1[y, x])
    ix = np.floor(sx)
    iy = np.floor(sy)
    inside = (ix >= ZERO) & (ix < wf) & (iy >= ZERO) & (iy < hf)
    j = f2i64(clamp_b(iy, ZERO, hm1) * wf + clamp_b(ix, ZERO, wm1))
    ds = _nan_inf_b(depth1f[j])
    off = off | (behind & inside & (ds < dq * KEEP3))
    return ONE if (entering & off & (dq > ZERO)) else ZERO


@njit(**INLINE)
def _bg_fill_px(s0, d0, s1, d1, sc2, scf, col0, col1, bil0, bil1, color, depth, mv, valid,
                color1, depth1, tk, out_c, out_d, out_m, out_v, code, x, y, yy, yh, w, w2,
                inplace):
    """bg_fill_kernel at (x, y), tk: _entering_px's value there. inplace: out_c, out_d,
    out_m are color, depth, mv themselves (never read here then), written where filled."""
    xx = (np.int64(x) >> 1) if sc2 else np.int64(x)
    xh = F32(I32(x)) + HALF
    sa = s0[y, x]
    da = d0[y, x]
    sb = s1[yy, xx]
    db = d1[yy, xx]
    h0 = sa >= 0
    h1 = sb >= 0
    t1 = h1 & ((not h0) | (db < da))
    t0 = h0 & (not t1)
    ac = max(sa, np.int64(0))
    bc = max(sb, np.int64(0))
    ay = _div(ac, w)
    ax = ac - ay * w
    by = _div(bc, w2)
    bx = bc - by * w2
    f = (valid[y, x] == U0) & (t0 | t1)
    dsel = db if t1 else da
    dq = _nan_inf_b(depth1[y, x])
    take = f & (tk != ZERO) & (dq < dsel)
    mx = (((F32(bx) + HALF) * scf) if t1 else (F32(ax) + HALF)) - xh
    my = (((F32(by) + HALF) * scf) if t1 else (F32(ay) + HALF)) - yh
    if inplace:  # the filled pixels only
        if f:
            for k in range(3):
                c = col1[k, by, bx] if t1 else col0[k, ay, ax]
                out_c[k, y, x] = sval_b(color1[k, y, x]) if take else c
            out_d[y, x] = dq if take else dsel
            out_m[0, y, x] = ZERO if take else mx
            out_m[1, y, x] = ZERO if take else my
    else:
        for k in range(3):
            c = col1[k, by, bx] if t1 else col0[k, ay, ax]
            c = c if f else color[k, y, x]
            out_c[k, y, x] = sval_b(color1[k, y, x]) if take else c
        dd = dsel if f else depth[y, x]
        out_d[y, x] = dq if take else dd
        mx = mx if f else mv[0, y, x]
        my = my if f else mv[1, y, x]
        out_m[0, y, x] = ZERO if take else mx
        out_m[1, y, x] = ZERO if take else my
    out_v[y, x] = np.uint8(1) if (f | (valid[y, x] != U0)) else U0
    rd = f & (not take)
    c0 = np.uint8(1) if (rd & t0 & bil0) else U0
    code[y, x] = np.uint8(2) if (rd & t1 & bil1) else c0


@njit(**KERNEL)
def bg_fill_kernel(s0, d0, s1, d1, sc2, scf, col0, col1, bil0, bil1, color, depth, mv,
                   valid, color1, depth1, mv1, a, entering, behind, out_c, out_d, out_m,
                   out_v, code, inplace):
    """background_fill after the two splats (bg_resolve_kernel's choice between the
    layers on the holes ~valid), entering_surface's test (with ``entering``; its ``behind``
    case with ``behind``: frame 1's depth read at the pixel containing q + a * mv1(q)) and
    the stage's selects, in one pass; code marks the filled pixels (not taken by the
    entering surface) whose colour bg_bilinear_kernel then replaces in out_c.

    Only holes change: a run of SPAN pixels without one passes colour, depth and vectors
    through (valid, code 0) and reads neither the splats nor frame 1, which is also why
    background_fill splats the cells its holes read only. inplace: out_c, out_d, out_m
    are color, depth, mv (scratch of the caller's), written at the filled holes only."""
    h, w = s0.shape
    w2 = s1.shape[1]
    wf = F32(w)
    hf = F32(h)
    wm1 = F32(w - 1)
    hm1 = F32(h - 1)
    depth1f = depth1.reshape(h * w)
    for pr in prange(h):
        y = np.int64(pr)
        yy = (y >> 1) if sc2 else y
        yh = F32(y) + HALF
        tk = np.empty(SPAN, dtype=np.float32)
        for xs in range((w + SPAN - 1) // SPAN):
            xa = np.int64(xs) * SPAN
            n = min(SPAN, w - xa)
            m = U0
            for i in range(n):
                m |= np.uint8(1) if valid[y, xa + i] == U0 else U0
            if m == U0:
                for i in range(n):
                    x = xa + i
                    out_v[y, x] = np.uint8(1)
                    code[y, x] = U0
                if not inplace:
                    for i in range(n):
                        x = xa + i
                        for k in range(3):
                            out_c[k, y, x] = color[k, y, x]
                        out_d[y, x] = depth[y, x]
                        out_m[0, y, x] = mv[0, y, x]
                        out_m[1, y, x] = mv[1, y, x]
                continue
            # entering_surface's test (its own gather loop)
            for i in range(n):
                tk[i] = _entering_px(mv1, depth1, depth1f, a, behind, entering, xa + i, y, yh,
                                     wf, hf, wm1, hm1, w)
            for i in range(n):
                _bg_fill_px(s0, d0, s1, d1, sc2, scf, col0, col1, bil0, bil1, color, depth,
                            mv, valid, color1, depth1, tk[i], out_c, out_d, out_m, out_v,
                            code, xa + i, y, yy, yh, w, w2, inplace)


@njit(**KERNEL)
def cells_of_kernel(holes, want):
    """want (h2, w2) uint8 = 1 where the 2 x 2 block of full pixels a half-size cell covers
    (rows 2y, 2y + 1, columns 2x, 2x + 1, within holes (H, W) uint8) holds a hole."""
    H, W = holes.shape
    h2, w2 = want.shape
    for pq in prange(h2):
        q = np.int64(pq)
        y0 = 2 * q
        y1 = min(y0 + 1, H - 1)
        for x in range(w2):
            x0 = 2 * np.int64(x)
            x1 = min(x0 + 1, W - 1)
            want[q, x] = holes[y0, x0] | holes[y0, x1] | holes[y1, x0] | holes[y1, x1]


@njit(**INLINE)
def _sample_layer_px(col, dep, valid, px, py, ss, qx, qy, tol, out, y, x):
    """_sample_layer at one pixel (q = (qx, qy)) for the fragment ss (flat index into the
    full-size layer grid) whose projected position is (px, py)[ss]; writes out[:, y, x]."""
    H, W = dep.shape
    sy_ = ss // W
    sx_ = ss - sy_ * W
    fxp = F32(sx_) + (qx - px[sy_, sx_])
    fyp = F32(sy_) + (qy - py[sy_, sx_])
    x0 = np.floor(fxp)
    y0 = np.floor(fyp)
    fx = fxp - x0
    fy = fyp - y0
    dref = dep[sy_, sx_]
    lim = dref * tol
    a0 = ZERO
    a1 = ZERO
    a2 = ZERO
    ws = ZERO
    Wf = F32(W)
    Hf = F32(H)
    for oy in range(2):
        wy = (ONE - fy) if oy == 0 else fy
        ty = y0 + F32(oy)
        for ox in range(2):
            wx = (ONE - fx) if ox == 0 else fx
            tx = x0 + F32(ox)
            inside = (tx >= ZERO) & (tx < Wf) & (ty >= ZERO) & (ty < Hf)
            j = f2i64(clamp_b(ty, ZERO, Hf - ONE) * Wf + clamp_b(tx, ZERO, Wf - ONE))
            jy = j // W
            jx = j - jy * W
            dj = dep[jy, jx]
            ok = inside and valid[jy, jx] != U0 and abs(dj - dref) <= lim
            wt = wx * wy if ok else ZERO
            a0 = a0 + col[0, jy, jx] * wt
            a1 = a1 + col[1, jy, jx] * wt
            a2 = a2 + col[2, jy, jx] * wt
            ws = ws + wt
    if ws > HALF:
        dv = max(ws, F32(1e-12))
        out[0, y, x] = a0 / dv
        out[1, y, x] = a1 / dv
        out[2, y, x] = a2 / dv
    else:
        out[0, y, x] = col[0, sy_, sx_]
        out[1, y, x] = col[1, sy_, sx_]
        out[2, y, x] = col[2, sy_, sx_]


@njit(**KERNEL)
def bg_bilinear_kernel(code, s0, s1, l0c, l0d, l0v, px0, py0, l1c, l1d, l1v, px1, py1, tol,
                       out_c):
    """The bilinear reads of project_background (filter='bilinear'): the pixels ``code``
    marks (few: the holes) read their layer at the exact sub-pixel place (_sample_layer)."""
    h, w = code.shape
    for pr in prange(h):
        y = np.int64(pr)
        qy = F32(y) + HALF
        for x in range(w):
            c = code[y, x]
            if c == U0:
                continue
            qx = F32(I32(x)) + HALF
            if c == np.uint8(1):
                _sample_layer_px(l0c, l0d, l0v, px0, py0, max(s0[y, x], np.int64(0)), qx, qy,
                                 tol, out_c, y, x)
            else:
                _sample_layer_px(l1c, l1d, l1v, px1, py1, max(s1[y, x], np.int64(0)), qx, qy,
                                 tol, out_c, y, x)


# ----------------------------------------------------------------------------- push-pull
# fgcli.ops.gffe.push_pull_fill with depth and far_bias >= 0, level by level: colour planes
# (3, h, w), depth plane, the weights w and wd as float32 0 / 1 planes. avg_pool2d (2x2,
# ceil_mode, count_include_pad=False) as ATen's CPU kernel computes it: a float sum from 0
# over the window's cells in row order, divided by their count, added to 0.

BIG30 = np.float32(1e30)
TINY30 = np.float32(1e-30)


@njit(**INLINE)
def _pp_level0(depth, valid, y, x):
    """Level 0 of the pyramid at pixel (y, x), made where it is read: (the depth where
    finite and positive else 0, the weight: 1 where valid, the depth weight: 1 where valid
    with such a depth)."""
    d = depth[y, x]
    fin = (d > ZERO) & (d < INF)
    v = valid[y, x] != U0
    return (d if fin else ZERO), (ONE if v else ZERO), (ONE if (v & fin) else ZERO)


@njit(**INLINE)
def _pp_down_px(xc, xd, wv, wdv, fb, nxc, nxd, nw, nwd, oy, ox, ya, yb, xa, xb, cnt, mb, mc,
                md):
    """pp_down_kernel at output pixel (oy, ox) from the 2x2 block of rows ya, yb and
    columns xa, xb (mb, mc, md: whether cells b, c, d exist, cnt their count with a)."""
    _pp_down_cells(xc, xd[ya, xa], xd[ya, xb], xd[yb, xa], xd[yb, xb], wv[ya, xa], wv[ya, xb],
                   wv[yb, xa], wv[yb, xb], wdv[ya, xa], wdv[ya, xb], wdv[yb, xa], wdv[yb, xb],
                   fb, nxc, nxd, nw, nwd, oy, ox, ya, yb, xa, xb, cnt, mb, mc, md)


@njit(**INLINE)
def _pp_down0_px(color, depth, valid, fb, nxc, nxd, nw, nwd, oy, ox, ya, yb, xa, xb, cnt, mb,
                 mc, md):
    """_pp_down_px on level 0, its planes made from depth and valid as they are read."""
    da, wa, va = _pp_level0(depth, valid, ya, xa)
    db, wb, vb = _pp_level0(depth, valid, ya, xb)
    dc, wc, vc = _pp_level0(depth, valid, yb, xa)
    dd_, wd_, vd = _pp_level0(depth, valid, yb, xb)
    _pp_down_cells(color, da, db, dc, dd_, wa, wb, wc, wd_, va, vb, vc, vd, fb, nxc, nxd, nw,
                   nwd, oy, ox, ya, yb, xa, xb, cnt, mb, mc, md)


@njit(**INLINE)
def _pp_down_cells(xc, da, db, dc, dd_, wa, wb, wc, wd_, va, vb, vc, vd, fb, nxc, nxd, nw, nwd,
                   oy, ox, ya, yb, xa, xb, cnt, mb, mc, md):
    """_pp_down_px with the block's depths (da .. dd_), weights (wa .. wd_) and depth
    weights (va .. vd) read."""
    ea = ((da if va > ZERO else BIG30) if wa > ZERO else ZERO)
    eb = ((db if vb > ZERO else BIG30) if wb > ZERO else ZERO)
    ec = ((dc if vc > ZERO else BIG30) if wc > ZERO else ZERO)
    ed = ((dd_ if vd > ZERO else BIG30) if wd_ > ZERO else ZERO)
    mx = ea
    mx = eb if (mb & (eb > mx)) else mx
    mx = ec if (mc & (ec > mx)) else mx
    mx = ed if (md & (ed > mx)) else mx
    thr = mx * fb
    ba = wa * (ONE if ea >= thr else ZERO)
    bb = wb * (ONE if eb >= thr else ZERO)
    bc = wc * (ONE if ec >= thr else ZERO)
    bd = wd_ * (ONE if ed >= thr else ZERO)
    s = ZERO + ba
    s = (s + bb) if mb else s
    s = (s + bc) if mc else s
    s = (s + bd) if md else s
    sw = ZERO + s / cnt
    den = max(sw, TINY30)
    for k in range(3):
        s = ZERO + sval_b(xc[k, ya, xa]) * ba
        s = (s + sval_b(xc[k, ya, xb]) * bb) if mb else s
        s = (s + sval_b(xc[k, yb, xa]) * bc) if mc else s
        s = (s + sval_b(xc[k, yb, xb]) * bd) if md else s
        sx = ZERO + s / cnt
        nxc[k, oy, ox] = (sx / den) if sw > ZERO else ZERO
    s = ZERO + va
    s = (s + vb) if mb else s
    s = (s + vc) if mc else s
    s = (s + vd) if md else s
    swd = ZERO + s / cnt
    s = ZERO + da * va
    s = (s + db * vb) if mb else s
    s = (s + dc * vc) if mc else s
    s = (s + dd_ * vd) if md else s
    sd = ZERO + s / cnt
    nxd[oy, ox] = (sd / max(swd, TINY30)) if swd > ZERO else ZERO
    nw[oy, ox] = ONE if sw > ZERO else ZERO
    nwd[oy, ox] = ONE if swd > ZERO else ZERO


@njit(**KERNEL)
def pp_down_kernel(xc, xd, wv, wdv, fb, nxc, nxd, nw, nwd):
    """One level down: far-biased weights (within fb of the 2x2 block's farthest depth),
    validity-weighted 2x2 averages of colour (xc, sanitised as read) and depth.

    The blocks of whole column pairs run in a loop of their own (columns 2 ox and
    2 ox + 1: strided loads LLVM vectorises as such), the last one of an odd width apart
    (its right cell is the left one; as a select in the same loop the column index was no
    longer affine and every read a gather: 3x slower)."""
    h, w = xd.shape
    h2, w2 = nxd.shape
    wp = w // 2  # blocks with two columns
    for pr in prange(h2):
        oy = np.int64(pr)
        ya = 2 * oy
        r1 = ya + 1 < h
        yb = ya + 1 if r1 else ya
        if r1:  # (versioned: with the flag a runtime value the loop stayed scalar)
            for ox in range(wp):
                _pp_down_px(xc, xd, wv, wdv, fb, nxc, nxd, nw, nwd, oy, ox, ya, ya + 1, 2 * ox,
                            2 * ox + 1, F32(4.0), True, True, True)
        else:  # (an odd height's last row)
            for ox in range(wp):
                _pp_down_px(xc, xd, wv, wdv, fb, nxc, nxd, nw, nwd, oy, ox, ya, ya, 2 * ox,
                            2 * ox + 1, F32(2.0), True, False, False)
        for ox in range(wp, w2):  # an odd width's last block: one column
            _pp_down_px(xc, xd, wv, wdv, fb, nxc, nxd, nw, nwd, oy, ox, ya, yb, 2 * ox,
                        2 * ox, F32(2 if r1 else 1), False, r1, False)


@njit(**KERNEL)
def pp_down0_kernel(color, depth, valid, fb, nxc, nxd, nw, nwd):
    """pp_down_kernel from level 0 (colour, depth (h, w) float32, valid (h, w) uint8), its
    depth and weight planes made as the blocks read them (_pp_level0): the same values,
    without three frame-sized planes written and read back (pp_final_kernel needs none of
    them)."""
    h, w = depth.shape
    h2, w2 = nxd.shape
    wp = w // 2
    for pr in prange(h2):
        oy = np.int64(pr)
        ya = 2 * oy
        r1 = ya + 1 < h
        yb = ya + 1 if r1 else ya
        if r1:  # (versioned as in pp_down_kernel)
            for ox in range(wp):
                _pp_down0_px(color, depth, valid, fb, nxc, nxd, nw, nwd, oy, ox, ya, ya + 1,
                             2 * ox, 2 * ox + 1, F32(4.0), True, True, True)
        else:
            for ox in range(wp):
                _pp_down0_px(color, depth, valid, fb, nxc, nxd, nw, nwd, oy, ox, ya, ya, 2 * ox,
                             2 * ox + 1, F32(2.0), True, False, False)
        for ox in range(wp, w2):
            _pp_down0_px(color, depth, valid, fb, nxc, nxd, nw, nwd, oy, ox, ya, yb, 2 * ox,
                         2 * ox, F32(2 if r1 else 1), False, r1, False)


@njit(**INLINE)
def _pp_up_px(xc, xd, wv, wdv, fxc, fxd, fw, fwd, oxc, oxd, ow, owd, y, x, yy, xx):
    a = wv[y, x]
    ad = wdv[y, x]
    for k in range(3):
        oxc[k, y, x] = sval_b(xc[k, y, x]) if a > ZERO else fxc[k, yy, xx]
    oxd[y, x] = xd[y, x] if ad > ZERO else fxd[yy, xx]
    ow[y, x] = max(a, fw[yy, xx])
    owd[y, x] = max(ad, fwd[yy, xx])


@njit(**KERNEL)
def pp_up_kernel(xc, xd, wv, wdv, fxc, fxd, fw, fwd, oxc, oxd, ow, owd):
    """One level up: the level's own values where it has weight, else the filled coarser
    level's (nearest upsampling). Pixel pairs (2 xx, 2 xx + 1) per iteration, so every
    index is affine in the loop counter (x >> 1 made the coarse reads gathers)."""
    h, w = xd.shape
    wp = w // 2
    for pr in prange(h):
        y = np.int64(pr)
        yy = y >> 1
        for xx in range(wp):
            _pp_up_px(xc, xd, wv, wdv, fxc, fxd, fw, fwd, oxc, oxd, ow, owd, y, 2 * xx, yy, xx)
            _pp_up_px(xc, xd, wv, wdv, fxc, fxd, fw, fwd, oxc, oxd, ow, owd, y, 2 * xx + 1, yy,
                      xx)
        for x in range(2 * wp, w):
            _pp_up_px(xc, xd, wv, wdv, fxc, fxd, fw, fwd, oxc, oxd, ow, owd, y, x, yy, x >> 1)


@njit(**KERNEL)
def pp_final_kernel(color, depth, valid, fxc, fxd, fwd, out_c, out_d):
    """Level 0 up, and the outputs: valid pixels keep (sanitised) colour and raw depth,
    the others take level 1's (its depth where its depth weight is set, else +inf; level
    0's own depth and weight, zero at an invalid pixel, are never taken there)."""
    h, w = depth.shape
    for pr in prange(h):
        y = np.int64(pr)
        yy = y >> 1
        for x in range(w):
            xx = np.int64(x) >> 1
            v = valid[y, x] != U0
            for k in range(3):
                out_c[k, y, x] = sval_b(color[k, y, x]) if v else fxc[k, yy, xx]
            dd = fxd[yy, xx] if fwd[yy, xx] > ZERO else INF
            out_d[y, x] = depth[y, x] if v else dd


# push-pull by tiles: the result at a hole is its colour chain's first level with weight
# (and its depth chain's): the levels of its aligned 2**K x 2**K tile decide it whenever
# that tile has a valid pixel and a valid one of finite depth (its level-K cell then has
# both weights), so a frame whose holes all lie in such tiles needs the pyramid of those
# tiles only, not of the frame (fgcli.kernels.ops.push_pull_fill).


@njit(**KERNEL)
def pp_tile_scan_kernel(depth, valid, K, holes, ok):
    """Per aligned tile of 2**K pixels a side (holes, ok: (ceil(h / 2**K), ceil(w / 2**K))
    uint8): holes = it has an invalid pixel, ok = it has a valid pixel and a valid one of
    finite positive depth. (Per band of tile rows, the flags of each column in vectorised
    row passes, then per tile: a loop per tile and row took 5-6 ms at 1080p.)"""
    h, w = depth.shape
    nty, ntx = holes.shape
    T = np.int64(1) << K
    for pty in prange(nty):
        ty = np.int64(pty)
        ah = np.zeros(w, dtype=np.uint8)
        av = np.zeros(w, dtype=np.uint8)
        af = np.zeros(w, dtype=np.uint8)
        for y in range(ty * T, min(h, ty * T + T)):
            for x in range(w):
                d = depth[y, x]
                v = valid[y, x] != U0
                ah[x] |= U0 if v else np.uint8(1)
                av[x] |= np.uint8(1) if v else U0
                af[x] |= np.uint8(1) if v & (d > ZERO) & (d < INF) else U0
        for tx in range(ntx):
            nh = U0
            nv = U0
            nf = U0
            for x in range(tx * T, min(w, tx * T + T)):
                nh |= ah[x]
                nv |= av[x]
                nf |= af[x]
            holes[ty, tx] = nh
            ok[ty, tx] = nv & nf


@njit(**ROWS)
def _pp_tiles_band(ty, color, depth, valid, fb, K, holes, out_c, out_d, inplace, c0, d0, w0,
                   e0, lc, ld, lw, le):
    """pp_tiles_kernel's band of tiles ty (one pass of its parallel loop), with the
    band's tile buffers."""
    h, w = depth.shape
    nty, ntx = holes.shape
    T = np.int64(1) << K
    y0 = ty * T
    y1 = min(h, y0 + T)
    if not inplace:
        for y in range(y0, y1):
            for k in range(3):
                for x in range(w):
                    out_c[k, y, x] = sval_b(color[k, y, x])
            for x in range(w):
                out_d[y, x] = depth[y, x]
    for tx in range(ntx):
        if holes[ty, tx] == U0:
            continue
        x0 = tx * T
        th = y1 - y0
        tw = min(w, x0 + T) - x0
        for y in range(th):  # level 0 of the tile: _pp_level0's planes
            for x in range(tw):
                for k in range(3):
                    c0[k, y, x] = color[k, y0 + y, x0 + x]
                d = depth[y0 + y, x0 + x]
                fin = (d > ZERO) & (d < INF)
                v = valid[y0 + y, x0 + x] != U0
                d0[y, x] = d if fin else ZERO
                w0[y, x] = ONE if v else ZERO
                e0[y, x] = ONE if (v & fin) else ZERO
        hk = th
        wk = tw
        # pp_down_kernel, in the tile (its row loops written out again: the frame's
        # kernel keeps them in its body, where LLVM vectorises them; not in a helper)
        for lv in range(1, K + 1):
            nh = (hk + 1) // 2
            nw = (wk + 1) // 2
            sc = c0 if lv == 1 else lc[lv - 1]
            sd = d0 if lv == 1 else ld[lv - 1]
            sw = w0 if lv == 1 else lw[lv - 1]
            se = e0 if lv == 1 else le[lv - 1]
            oc = lc[lv]
            od = ld[lv]
            ow = lw[lv]
            oe = le[lv]
            wp = wk // 2
            for oy in range(nh):
                ya = 2 * oy
                r1 = ya + 1 < hk
                yb = ya + 1 if r1 else ya
                cnt2 = F32(2 if r1 else 1) * F32(2)
                for ox in range(wp):
                    _pp_down_px(sc, sd, sw, se, fb, oc, od, ow, oe, oy, ox, ya, yb, 2 * ox,
                                2 * ox + 1, cnt2, True, r1, r1)
                for ox in range(wp, nw):
                    _pp_down_px(sc, sd, sw, se, fb, oc, od, ow, oe, oy, ox, ya, yb, 2 * ox,
                                2 * ox, F32(2 if r1 else 1), False, r1, False)
            hk = nh
            wk = nw
        for y in range(th):  # the holes: each chain's first level with weight
            for x in range(tw):
                if w0[y, x] != ZERO:
                    continue
                for lv in range(1, K + 1):
                    cy = y >> lv
                    cx = x >> lv
                    if lw[lv, cy, cx] > ZERO:
                        for k in range(3):
                            out_c[k, y0 + y, x0 + x] = sval_b(lc[lv, k, cy, cx])
                        break
                dd = INF
                for lv in range(1, K + 1):
                    cy = y >> lv
                    cx = x >> lv
                    if le[lv, cy, cx] > ZERO:
                        dd = ld[lv, cy, cx]
                        break
                out_d[y0 + y, x0 + x] = dd
    if inplace:  # (after the band's tiles have read it)
        for y in range(y0, y1):
            for k in range(3):
                r = out_c[k, y]
                e = np.int64(0)  # the largest exponent field: all ones for inf / NaN
                for x in range(w):
                    e = max(e, np.int64(np.float32(r[x]).view(np.int32) & 0x7F800000))
                if e == 0x7F800000:
                    for x in range(w):
                        r[x] = sval_b(r[x])


@njit(**KERNEL)
def pp_tiles_kernel(color, depth, valid, fb, K, holes, out_c, out_d, inplace):
    """push_pull_fill's result when every tile with a hole is ok (pp_tile_scan_kernel):
    valid pixels keep their (sanitised) colour and raw depth (pp_final_kernel); in each
    tile with holes, levels 1..K of the tile by pp_down_kernel's arithmetic (the same
    2x2 blocks: tiles are aligned, and their rows / columns at the frame's last edge are
    the frame's), then each hole takes the (sanitised) colour of its first level with
    colour weight and the depth of its first level with depth weight, as the up pass
    hands them down.

    inplace: out_c, out_d are color, depth themselves (the caller's scratch): a band's
    tiles first read their pixels and write their holes, then the band's colour rows are
    sanitised where they hold a value that is not finite (a row that does not is only
    read); valid depths stay as they are."""
    h, w = depth.shape
    nty, ntx = holes.shape
    T = np.int64(1) << K
    S = max(np.int64(1), T >> 1)
    for pty in prange(nty):
        ty = np.int64(pty)
        c0 = np.empty((3, T, T), dtype=np.float32)
        d0 = np.empty((T, T), dtype=np.float32)
        w0 = np.empty((T, T), dtype=np.float32)
        e0 = np.empty((T, T), dtype=np.float32)
        lc = np.empty((K + 1, 3, S, S), dtype=np.float32)
        ld = np.empty((K + 1, S, S), dtype=np.float32)
        lw = np.empty((K + 1, S, S), dtype=np.float32)
        le = np.empty((K + 1, S, S), dtype=np.float32)
        _pp_tiles_band(ty, color, depth, valid, fb, K, holes, out_c, out_d, inplace, c0, d0, w0,
                       e0, lc, ld, lw, le)


# ----------------------------------------------------------------------------- hole fills


@njit(**KERNEL)
def reproject_took_kernel(px, py, ok, valid, depth, depth1, clamp, keep, took, flow):
    """reproject_fill without a border, up to the sampling: (px, py, ok) the hole's proxy
    point projected into frame 1 (clamped on screen when ``clamp``); took = _proxy_took
    (keep = 1 - depth_tol), flow = its offset where took, else 0."""
    h, w = depth.shape
    hs, ws = depth1.shape
    wf = F32(w)
    hf = F32(h)
    wsf = F32(ws)
    hsf = F32(hs)
    d1f = depth1.reshape(hs * ws)  # (flat: the pixel index reads it without a division)
    for pr in prange(h):
        y = np.int64(pr)
        yh = F32(y) + HALF
        for x in range(w):
            o = ok[y, x] != U0
            sx = px[y, x]
            sy = py[y, x]
            cx = clamp_b(sx, HALF, wf - HALF)
            cy = clamp_b(sy, HALF, hf - HALF)
            sx = cx if (o & clamp) else sx
            sy = cy if (o & clamp) else sy
            ix = np.floor(sx)
            iy = np.floor(sy)
            inside = (ix >= ZERO) & (ix < wsf) & (iy >= ZERO) & (iy < hsf)
            j = f2i64(clamp_b(iy, ZERO, hsf - ONE) * wsf + clamp_b(ix, ZERO, wsf - ONE))
            s = d1f[j]
            s = ZERO if s != s else s  # nan_to_num(nan=0): +-inf -> +-float32 max
            s = FMAX if s > FMAX else s
            s = -FMAX if s < -FMAX else s
            dq = depth[y, x]
            t = (valid[y, x] == U0) & o & inside & (s >= dq * keep)
            took[y, x] = np.uint8(1) if t else U0
            flow[0, y, x] = (sx - (F32(I32(x)) + HALF)) if t else ZERO
            flow[1, y, x] = (sy - yh) if t else ZERO


@njit(**INLINE)
def _reproject_mv_run(px, py, ok, valid, depth, d1f, clamp, keep, mv0, took, flow, mv_out,
                      inplace, y, yh, xa, xb, wf, hf, wsf, hsf):
    """reproject_mv_kernel's pixels xa..xb of row y (a row with a hole)."""
    for x in range(xa, xb):
        o = ok[y, x] != U0
        sx = px[y, x]
        sy = py[y, x]
        cx = clamp_b(sx, HALF, wf - HALF)
        cy = clamp_b(sy, HALF, hf - HALF)
        sx = cx if (o & clamp) else sx
        sy = cy if (o & clamp) else sy
        ix = np.floor(sx)
        iy = np.floor(sy)
        inside = (ix >= ZERO) & (ix < wsf) & (iy >= ZERO) & (iy < hsf)
        j = f2i64(clamp_b(iy, ZERO, hsf - ONE) * wsf + clamp_b(ix, ZERO, wsf - ONE))
        s = d1f[j]
        s = ZERO if s != s else s  # nan_to_num(nan=0): +-inf -> +-float32 max
        s = FMAX if s > FMAX else s
        s = -FMAX if s < -FMAX else s
        dq = depth[y, x]
        vv = valid[y, x] != U0
        t = (not vv) & o & inside & (s >= dq * keep)
        took[y, x] = np.uint8(1) if t else U0
        f0 = (sx - (F32(I32(x)) + HALF)) if t else ZERO
        f1 = (sy - yh) if t else ZERO
        flow[0, y, x] = f0
        flow[1, y, x] = f1
        if inplace:
            if not vv:
                mv_out[0, y, x] = f0
                mv_out[1, y, x] = f1
        else:
            m0 = mv0[0, y, x] if vv else ZERO
            m1 = mv0[1, y, x] if vv else ZERO
            mv_out[0, y, x] = f0 if t else m0
            mv_out[1, y, x] = f1 if t else m1


@njit(**KERNEL)
def reproject_mv_kernel(px, py, ok, valid, depth, depth1, clamp, keep, mv0, took, flow,
                        mv_out, rows, some, inplace):
    """reproject_took_kernel, and the hole fill's vectors: flow where took, else mv0 on
    the valid pixels, else 0. (The proxy test is written out in both kernels: as a shared
    inlined per-pixel helper the hole-fill stage measured 98 against 57 ms at 1080p.)
    With ``some``, rows y with rows[y] == 0 have no hole: nothing is taken there, and
    px, py, ok are not read (reproject_kernel left them unwritten). inplace (with
    ``some``): mv_out is mv0 itself, written at the holes only (mv0 never read), and
    flow only in the rows with a hole. In a row with a hole, a run of SPAN pixels without
    one (a moving camera's rows nearly all hold a hole, most of their runs none) takes
    nothing and keeps its vectors, and its flow is not written: it is sample_where_kernel's
    run, skipped where nothing is taken, reading no flow there."""
    h, w = depth.shape
    hs, ws = depth1.shape
    wf = F32(w)
    hf = F32(h)
    wsf = F32(ws)
    hsf = F32(hs)
    d1f = depth1.reshape(hs * ws)  # (flat: the pixel index reads it without a division)
    for pr in prange(h):
        y = np.int64(pr)
        yh = F32(y) + HALF
        if some and rows[y] == U0:
            if inplace:
                for x in range(w):
                    took[y, x] = U0
                continue
            for x in range(w):
                vv = valid[y, x] != U0
                took[y, x] = U0
                flow[0, y, x] = ZERO
                flow[1, y, x] = ZERO
                mv_out[0, y, x] = mv0[0, y, x] if vv else ZERO
                mv_out[1, y, x] = mv0[1, y, x] if vv else ZERO
            continue
        vr = valid[y]
        tr = took[y]
        for x in range(w):  # (the whole row as if nothing were taken; vectorised)
            tr[x] = U0
        if not inplace:
            for c in range(2):
                mo = mv_out[c, y]
                mi = mv0[c, y]
                for x in range(w):
                    mo[x] = mi[x] if vr[x] != U0 else ZERO
        for xs in range((w + SPAN - 1) // SPAN):
            xa = np.int64(xs) * SPAN
            xb = min(xa + SPAN, w)
            m = np.uint8(1)
            for x in range(xa, xb):
                m = min(m, vr[x])
            if m != U0:  # no hole in the run: nothing taken; its flow is not read
                continue
            _reproject_mv_run(px, py, ok, valid, depth, d1f, clamp, keep, mv0, took, flow,
                              mv_out, inplace, y, yh, xa, xb, wf, hf, wsf, hsf)


@njit(**KERNEL)
def vector_rule_kernel(mv1, depth1, valid, a, keep, took, flow, depth, mv):
    """vector_rule_fill up to the sampling, in place: extrap_hole_fill on the holes (frame 1
    read ``a * mv1(q)`` away, the vector where that is not nearer than q by more than
    1 - keep), took = holes whose vector is not zero; depth and mv (the caller's own
    planes: its copies, or scratch) are written where took and nowhere else. flow: the
    vector where took, 0 at the other pixels of a row with a hole; rows without one are
    not written (the sampling reads no flow there: it reads only runs of pixels with one
    taken). A row's holes first (one vectorised test), then, in a row with one, zeros for
    every pixel (vectorised) and the rule at its holes alone: eight pixels' valid flags
    tested as one word, a word without a hole skipped (the rule per pixel over the row,
    its depth read a scalar gather at every pixel, took 3-5 ms per 1080p frame)."""
    h, w = depth1.shape
    n8 = w // 8
    lo = F32(-0.5)
    hx = F32(w - 0.5)
    hy = F32(h - 0.5)
    wm1 = F32(w - 1)
    hm1 = F32(h - 1)
    for pr in prange(h):
        y = np.int64(pr)
        yf = F32(y)
        vr = valid[y]
        tr = took[y]
        m = np.uint8(1)
        for x in range(w):
            m &= vr[x]
        if m != U0:  # no hole in the row
            for x in range(w):
                tr[x] = U0
            continue
        for x in range(w):
            tr[x] = U0
            flow[0, y, x] = ZERO
            flow[1, y, x] = ZERO
        vw = valid[y, :n8 * 8].view(np.uint64)
        for b in range(n8 + 1):  # (the last "word": the row's w % 8 pixels)
            if b < n8 and vw[b] == ALL1:
                continue
            for x in range(8 * b, min(8 * b + 8, w)):
                if vr[x] != U0:
                    continue
                mx = smv_b(mv1[0, y, x]) * a
                my = smv_b(mv1[1, y, x]) * a
                sx = F32(I32(x)) + mx
                sy = yf + my
                inside = (sx >= lo) & (sx < hx) & (sy >= lo) & (sy < hy)
                ix = f2i64(clamp_b(np.floor(sx + HALF), ZERO, wm1))
                iy = f2i64(clamp_b(np.floor(sy + HALF), ZERO, hm1))
                ds = sdepth_b(depth1[iy, ix])
                do = sdepth_b(depth1[y, x])
                bg = inside & (not (ds < do * keep))
                if bg & ((mx != ZERO) | (my != ZERO)):
                    tr[x] = np.uint8(1)
                    flow[0, y, x] = mx
                    flow[1, y, x] = my
                    depth[y, x] = ds
                    mv[0, y, x] = mx
                    mv[1, y, x] = my


# ----------------------------------------------------------------------------- history
# fgcli.ops.gffe.track_history with a camera history. Only the pixels the static test
# finds dynamic with x' on screen (``use``; a few percent of a frame) read the previous
# frame: every other pixel's trajectory is P_0 repeated. So one pass unprojects P_0, tests
# it against its own projection into the previous camera and finds x' (hist_p_kernel;
# the sky's directions follow in geom.unproject_sky_kernel, and the sky is never
# dynamic), the match search runs over the selected pixels (hist_match_kernel; the
# logarithms come from torch.log, as the reference computes them), and the trajectory is
# P_0 copied (row by row in hist_p_kernel), then patched at the selected pixels with P'_0
# unprojected there alone
# (hist_sel_kernel; where P'_0 is the sky it is never taken, so it needs no sky pass).

@njit(**INLINE)
def _hist_xp(mv1, y, x):
    """x' = the centre of pixel (x, y) + mv1 there (sanitised), as float32 (x, y)."""
    return ((F32(I32(x)) + HALF) + smv_b(mv1[0, y, x]),
            (F32(y) + HALF) + smv_b(mv1[1, y, x]))


@njit(**KERNEL)
def hist_p_kernel(depth, gx, gy, kx, ky, A, M, V, P, hw, hh, mv1, thr2, p, ss, nsky, use,
                  nuse, older):
    """P_0 = unproject_kernel's surface points of depth (h, w) at the pixel centres (gx
    (1, w), gy (h, 1); kx, ky, A, M its coefficients) into p (4, h, w), with ss and nsky
    as it writes them; then per pixel x' = x + mv1 (sanitised: _hist_xp) and the static
    test against P_0 projected into the previous camera (project_kernel's _project_px; V,
    P, hw, hh its coefficients): use = dynamic, a surface, x' on screen; nuse (h,) int64
    their count per row. x' and the pixel containing it are not stored: hist_at_kernel
    makes them again at the selected pixels alone (a few percent of a frame; three
    frame-sized planes, 25 MB at 1080p, were written here and read there). Each row:
    the unprojection's loop, the sky count's, the test's on the row just written, the
    count's (each loop vectorised on its own). older (j, 4, h, w): the trajectory's older
    planes, P_0's row copied into each while it is in cache, on the rows without sky (the
    caller copies the sky rows after the sky pass). Against one copy of the whole plane
    afterwards, in one process: 0.4-0.9 ms less per 1080p frame without sky, 0.1-0.2 ms
    on the benchmark's frames (sky in 508 of 1080 rows)."""
    h, w = depth.shape
    wf = F32(w)
    hf = F32(h)
    RT = ray_tables(gx, gy, kx, ky, A)
    for pr in prange(h):
        y = np.int64(pr)
        o0 = p[0, y]
        o1 = p[1, y]
        o2 = p[2, y]
        o3 = p[3, y]
        nsky[y] = _unproject_row(gx, gy, y, kx, ky, depth[y], A, M, o0, o1, o2, o3, ss[y], RT)
        for x in range(w):
            qx, qy, _, ok = _project_px(o0[x], o1[x], o2[x], o3[x], V, P, hw, hh)
            a, b = _hist_xp(mv1, y, x)
            ex = qx - a
            ey = qy - b
            dist2 = ex * ex + ey * ey
            dyn = ok & (dist2 > thr2) & (o3[x] > ZERO)
            ix = np.floor(a)
            iy = np.floor(b)
            inside = (ix >= ZERO) & (ix < wf) & (iy >= ZERO) & (iy < hf)
            use[y, x] = np.uint8(1) if (dyn & inside) else U0
        n = 0
        ur = use[y]
        for x in range(w):
            n += np.int64(ur[x])
        nuse[y] = n
        if nsky[y] == 0:
            copy_row_planes(p, older, y)


@njit(**KERNEL)
def select_rows_kernel(mask, end, sel):
    """np.flatnonzero of mask (h, w) uint8 (0 or 1) into sel, row by row in parallel: end
    (h,) the cumulative count of set pixels through each row (~0.3 ms for a 1080p mask
    against flatnonzero's ~6)."""
    h, w = mask.shape
    for pr in prange(h):
        y = np.int64(pr)
        j = end[y - 1] if y > 0 else np.int64(0)
        if end[y] == j:
            continue
        mr = mask[y]
        for x in range(w):
            if mr[x] != U0:
                sel[j] = y * w + x
                j += 1


@njit(**INLINE)
def _log_arg(v):
    """torch.nan_to_num(v, nan=0, posinf=1e30).clamp_min(1e-30): the argument of the
    match search's logarithms (exact: no rounding)."""
    r = F32(1e30) if v == INF else v
    r = F32(1e-30) if r != r else r
    return max(r, F32(1e-30))


@njit(**INLINE)
def _match_tap(ix, iy, t, w, h):
    """The flat index of _match_idx's tap t (its order: offsets 0, -1, 1 in y, then x)."""
    r = t // 3
    c = t - 3 * r
    oy = r - 1 if r == 2 else -r  # 0, -1, 1
    ox = c - 1 if c == 2 else -c
    return min(max(iy + oy, 0), h - 1) * w + min(max(ix + ox, 0), w - 1)


@njit(**KERNEL)
def hist_at_kernel(sel, mv1, xs, ys, ids):
    """At the selected pixels sel (flat, (n,)): x' (hist_p_kernel's, _hist_xp) into xs,
    ys and the pixel containing it, clamped to the frame, into ids (flat)."""
    h, w = mv1.shape[1], mv1.shape[2]
    wf = F32(w)
    wm1 = F32(w - 1)
    hm1 = F32(h - 1)
    for i in prange(sel.shape[0]):
        s = sel[i]
        y = s // w
        x = s - y * w
        a, b = _hist_xp(mv1, y, x)
        xs[i] = a
        ys[i] = b
        # (in float32, as the reference: exact below 2**24 pixels, its rounding above)
        ids[i] = f2i64(clamp_b(np.floor(b), ZERO, hm1) * wf + clamp_b(np.floor(a), ZERO, wm1))


@njit(**INLINE)
def _match_base(xs, ys, w, h, i):
    ix = f2i64(clamp_b(np.floor(xs[i]), ZERO, F32(w - 1)))
    iy = f2i64(clamp_b(np.floor(ys[i]), ZERO, F32(h - 1)))
    return ix, iy


@njit(**KERNEL)
def hist_taps_kernel(sel, depth0, depth1, xs, ys, out):
    """The arguments of _match_idx's logarithms at the selected pixels sel (flat; xs, ys
    their x', hist_at_kernel's): out (n, 10) float32, columns 0-8 depth0 at the 3x3 taps
    around x' (the reference's order), column 9 depth1 at the pixel itself, each through
    _log_arg. The caller takes torch.log of out in place: the reference's values (its
    logarithms of the whole frame, read at the taps; torch.log's result for an element
    does not depend on its position, tests/test_kernels.py::test_torch_math_position_free);
    10 logarithms per dynamic pixel instead of the whole frame's."""
    h, w = depth1.shape
    d0 = depth0.reshape(-1)
    for i in prange(sel.shape[0]):
        s = sel[i]
        y = s // w
        x = s - y * w
        ix, iy = _match_base(xs, ys, w, h, i)
        for t in range(9):
            out[i, t] = _log_arg(d0[_match_tap(ix, iy, t, w, h)])
        out[i, 9] = _log_arg(depth1[y, x])


@njit(**KERNEL)
def hist_match_kernel(lg, xs, ys, w, h, eps, lim, ids, fb):
    """_match_idx on the selected pixels (xs, ys their x', ids the pixels containing it,
    hist_at_kernel's; lg (n, 10) the logarithms of hist_taps_kernel's arguments): of the
    3x3 pixels around x', the first whose log depth0 is nearer to the pixel's log depth1
    than the best so far by more than eps (taps in the reference's order); ids updated,
    fb (n,) = no tap within lim."""
    for i in prange(ids.shape[0]):
        ix, iy = _match_base(xs, ys, w, h, i)
        l1 = lg[i, 9]
        best = INF
        bj = ids[i]
        for t in range(9):
            err = abs(lg[i, t] - l1)
            better = err < best - eps
            best = err if better else best
            bj = _match_tap(ix, iy, t, w, h) if better else bj
        ids[i] = bj
        fb[i] = np.uint8(1) if best > lim else U0


@njit(**KERNEL)
def hist_sel_kernel(sel, p, ids, fb, depth1, depth0, from_prev, xs, ys, kx, ky, A, M, prev,
                    nprev, out, dyn):
    """The trajectory at the selected pixels sel (flat; xs, ys their x', ids the pixel
    each reads, fb where the match fell back: (n,) each; out (k, 4, H, W) holds P_0 in
    every plane, dyn zeros): P'_0 = the previous frame's point at x' (depth0 at the pixel
    ids, or depth1 where the match fell back, unprojected at x' with the previous
    camera's coefficients kx, ky, A, M; from_prev: prev[0] read at ids), taken where it is
    a surface of P_0's kind; P_i (i >= 2) = prev[i - 1] at ids (the fallback's point where
    fb) where prev has it (i - 1 < nprev) and its kind is P_0's, else P'_0. dyn = where
    P'_0 is taken. Unused inputs are stand-ins of the right kind."""
    k = out.shape[0]
    h, w = depth1.shape
    pvf = prev.reshape((prev.shape[0], 4, prev.shape[2] * prev.shape[3]))
    d0f = depth0.reshape(h * w)
    for i in prange(sel.shape[0]):
        s = sel[i]
        y = s // w
        x = s - y * w
        n = ids[i]
        f = fb[i] != U0
        if from_prev and not f:
            q0 = pvf[0, 0, n]
            q1 = pvf[0, 1, n]
            q2 = pvf[0, 2, n]
            q3 = pvf[0, 3, n]
        else:
            d = depth1[y, x] if f else d0f[n]
            q0, q1, q2, q3, _ = _surface_px(xs[i] * kx - ONE, ONE - ys[i] * ky, d, A, M)
        p3 = p[3, y, x]
        if not ((q3 == p3) & (q3 > ZERO)):
            continue
        dyn[y, x] = np.uint8(1)
        out[1, 0, y, x] = q0
        out[1, 1, y, x] = q1
        out[1, 2, y, x] = q2
        out[1, 3, y, x] = q3
        for j in range(2, k):
            if j - 1 < nprev and not f:
                if pvf[j - 1, 3, n] == p3:
                    for c in range(4):
                        out[j, c, y, x] = pvf[j - 1, c, n]
            else:
                out[j, 0, y, x] = q0  # (where f, prev's plane is the fallback's point too)
                out[j, 1, y, x] = q1
                out[j, 2, y, x] = q2
                out[j, 3, y, x] = q3


# ----------------------------------------------------------------------------- window
# median_depth: an exact selection by the float32 bits (finite positive floats order as
# their bit patterns): a histogram of the top 16 bits, then one of the low 16 bits within
# the bucket that holds the rank.

@njit(**KERNEL)
def bits_count_kernel(d, top, shift, mask, hist, bmin, bmax):
    """hist (nch, nbins) int64, zeroed: per chunk of d (flat float32), the finite positive
    values counted by (bits >> shift) & mask; with top >= 0 only those whose top 16 bits
    are ``top`` (the second pass). In blocks: the bins of 1024 values (-1: not counted)
    in a vectorised loop, then runs of one bin counted in a register and added once
    (neighbouring depths share their top bits; 2x faster than an increment per value).

    bmin, bmax (nch * blocks per chunk,) int32: the first pass (top < 0) writes each
    block's least and greatest counted bits (bmin > bmax: none); the second skips the
    blocks whose top bits cannot be ``top`` (a depth map's blocks of 1024 neighbouring
    pixels span few top-bit values, so it reads a few of them)."""
    n = d.shape[0]
    nch = hist.shape[0]
    step = (n + nch - 1) // nch
    nbpc = (step + 1023) // 1024
    big = np.int32(0x7FFFFFFF)
    for c in prange(nch):
        a = c * step
        b = min(n, a + step)
        kb = np.empty(1024, dtype=np.int32)
        cur = np.int32(-1)
        cnt = np.int64(0)
        for s in range(a, b, 1024):
            e = min(b, s + 1024)
            blk = c * nbpc + (s - a) // 1024
            if top >= 0 and not ((bmin[blk] >> 16) <= top) & (top <= (bmax[blk] >> 16)):
                continue
            lo = big
            hi = np.int32(-1)
            ds = d[s:e]  # (a view: d[i] for i from s, of unknown sign, made gathers)
            for i in range(e - s):
                v = ds[i]
                bv = np.float32(v).view(np.int32)
                ok = (v > ZERO) & (v < INF) & ((top < 0) | ((bv >> 16) == top))
                kb[i] = ((bv >> shift) & mask) if ok else np.int32(-1)
                lo = min(lo, bv if ok else big)
                hi = max(hi, bv if ok else np.int32(-1))
            if top < 0:
                bmin[blk] = lo
                bmax[blk] = hi
            for i in range(e - s):
                k = kb[i]
                if k != cur:
                    if cur >= 0:
                        hist[c, cur] += cnt
                    cur = k
                    cnt = np.int64(0)
                cnt += 1
        if cur >= 0:
            hist[c, cur] += cnt


def _blocks(n, nch):
    """bits_count_kernel's block bounds arrays for n values in nch chunks."""
    nb = nch * ((((n + nch - 1) // nch) + 1023) // 1024)
    return np.empty(max(nb, 1), dtype=np.int32), np.empty(max(nb, 1), dtype=np.int32)


def bits_hist(d, nch=4):
    """((32768,) int64: the finite positive values of d counted by their top 16 bits,
    the blocks' bounds for bits_rank)."""
    hist = np.zeros((nch, 32768), dtype=np.int64)
    bounds = _blocks(d.shape[0], nch)
    bits_count_kernel(d, np.int32(-1), np.int32(16), np.int32(0x7FFF), hist, *bounds)
    return hist.sum(0), bounds


def bits_rank(d, top, rank, bounds, nch=4):
    """The float32 bits of the value of rank ``rank`` (0-based) among the finite positive
    values of d whose top 16 bits are ``top`` (the chunks counted in parallel: one serial
    pass took 3.1 ms over a 1080p frame, the parallel one 1.9-2.4; bounds: bits_hist's,
    for the same d and nch, so that only blocks that can hold such values are read)."""
    lo = np.zeros((nch, 65536), dtype=np.int64)
    bits_count_kernel(d, np.int32(top), np.int32(0), np.int32(0xFFFF), lo, *bounds)
    cum = np.cumsum(lo.sum(0))
    j = int(np.searchsorted(cum, rank, side="right"))
    return np.int32(-1) if j >= 65536 else np.int32((top << 16) | j)


# ----------------------------------------------------------------------------- collection
# fgcli.ops.gffe.collect_background with previous layers (edge_guard off): the new layer 0
# (col_init_kernel), the two cases of the previous layer 0's fragments (col_case_kernel),
# the previous layer 1's fragments behind layer 0 into free cells (col_behind_kernel), the
# splats (splat_min_kernel) and their winners written into the layers (layer_fill_kernel).

@njit(**ROWS)
def _col_init_rows(ya, yb, color1, depth1, static, d1, l0c, l0d, l0v):
    """col_init_kernel's rows ya..yb. A ROWS body (arrays without aliases, no runtime
    checks) with every load made before the selects: in the parallel loop's body the
    vectorised loop was compiled, yet the pipeline ran its scalar twin, and the colour
    read under the flag became a masked load."""
    w = depth1.shape[1]
    for y in range(ya, yb):
        for x in range(w):
            v = depth1[y, x]
            s = static[y, x]
            c0 = color1[0, y, x]
            c1 = color1[1, y, x]
            c2 = color1[2, y, x]
            r = FMAX if v == INF else v
            r = -FMAX if v == -INF else r
            r = ZERO if v != v else r
            d1[y, x] = r
            u = (r > ZERO) & (s != U0)
            l0c[0, y, x] = sval_b(c0) if u else ZERO
            l0c[1, y, x] = sval_b(c1) if u else ZERO
            l0c[2, y, x] = sval_b(c2) if u else ZERO
            l0d[y, x] = r if u else INF
            l0v[y, x] = np.uint8(u)


@njit(**KERNEL)
def col_init_kernel(color1, depth1, static, d1, l0c, l0d, l0v):
    """d1 = nan_to_num(depth1, nan=0) (+-inf -> +-float32 max); layer 0 = the usable
    (d1 > 0, static) pixels' sanitised colour and d1, else 0 / +inf."""
    h = depth1.shape[0]
    nch = min(h, 64)
    for ch in prange(nch):
        ya = np.int64(ch) * h // nch
        yb = (np.int64(ch) + 1) * h // nch
        _col_init_rows(ya, yb, color1, depth1, static, d1, l0c, l0d, l0v)


@njit(**KERNEL)
def max3_kernel(src, out):
    """out (h, w) = the maximum of src over each pixel's 3x3 neighbourhood, cells outside
    the frame left out (max_pool2d without its padding); src holds no NaN. Per row: the
    column maxima over the rows in the frame into a -inf-padded row buffer, then three
    taps of it (contiguous loops)."""
    h, w = src.shape
    for pr in prange(h):
        y = np.int64(pr)
        vm = np.empty(w + 2, dtype=np.float32)
        vm[0] = -INF
        vm[w + 1] = -INF
        ya = max(y - 1, np.int64(0))
        yb = min(y + 1, h - 1)
        for x in range(w):
            vm[x + 1] = src[ya, x]
        for yy in range(ya + 1, yb + 1):
            for x in range(w):
                v = src[yy, x]
                vm[x + 1] = v if v > vm[x + 1] else vm[x + 1]
        for x in range(w):
            m = vm[x]
            m = vm[x + 1] if vm[x + 1] > m else m
            out[y, x] = vm[x + 2] if vm[x + 2] > m else m


@njit(**KERNEL)
def col_case_kernel(px, py, dn, ok, far3, l0v, d1, tol, case1, case2):
    """The previous layer 0's fragments (at (px, py), depth dn, ok) against the new layer
    0 at the pixel containing them: case 1 (an invalid cell, the fragment behind frame 1's
    depth there or frame 1 without a surface), case 2 (a valid cell, the fragment deeper
    than the cell's whole 3x3 neighbourhood, max_pool2d's padding left out: far3 =
    max3_kernel of the new layer 0's depth, one read per fragment instead of nine)."""
    h, w = px.shape
    wf = F32(w)
    hf = F32(h)
    wm1 = F32(w - 1)
    hm1 = F32(h - 1)
    for pr in prange(h):
        y = np.int64(pr)
        for x in range(w):
            ix = np.floor(px[y, x])
            iy = np.floor(py[y, x])
            inside = (ix >= ZERO) & (ix < wf) & (iy >= ZERO) & (iy < hf) & (ok[y, x] != U0)
            n = f2i64(clamp_b(iy, ZERO, hm1) * wf + clamp_b(ix, ZERO, wm1))
            ny = _div(n, w)
            nx = n - ny * w
            av = l0v[ny, nx] != U0
            ad1 = d1[ny, nx]
            far = far3[ny, nx]
            d = dn[y, x]
            c1 = inside & (not av) & ((d > ad1 * tol) | (ad1 <= ZERO))
            c2 = inside & av & (d > far * tol)
            case1[y, x] = np.uint8(1) if c1 else U0
            case2[y, x] = np.uint8(1) if c2 else U0


@njit(**KERNEL)
def col_behind_kernel(px, py, dn, ok, l0d, l0v, d1, l1v, tol, sc, out):
    """The previous layer 1's fragments: behind the new layer 0 (or frame 1's depth where
    layer 0 is empty) at the pixel containing them, and landing on a free layer 1 cell."""
    h, w = l0d.shape
    h2, w2 = l1v.shape
    hs, ws = px.shape
    wf = F32(w)
    hf = F32(h)
    w2f = F32(w2)
    h2f = F32(h2)
    # flat views: a flat pixel index reads them without a division
    l0vf = l0v.reshape(l0v.size)
    l0df = l0d.reshape(l0d.size)
    d1f = d1.reshape(d1.size)
    l1vf = l1v.reshape(l1v.size)
    for pr in prange(hs):
        y = np.int64(pr)
        for x in range(ws):
            a = px[y, x]
            b = py[y, x]
            ix = np.floor(a)
            iy = np.floor(b)
            inside = (ix >= ZERO) & (ix < wf) & (iy >= ZERO) & (iy < hf) & (ok[y, x] != U0)
            n = f2i64(clamp_b(iy, ZERO, hf - ONE) * wf + clamp_b(ix, ZERO, wf - ONE))
            av = l0vf[n] != U0
            ad = l0df[n] if av else d1f[n]
            d = dn[y, x]
            beh = inside & (d > ad * tol) & (av | (ad > ZERO))
            jx = np.floor(a / sc)
            jy = np.floor(b / sc)
            m = f2i64(clamp_b(jy, ZERO, h2f - ONE) * w2f + clamp_b(jx, ZERO, w2f - ONE))
            free = l1vf[m] == U0
            out[y, x] = np.uint8(1) if (beh & free) else U0


@njit(**KERNEL)
def row_counts_kernel(mask, counts):
    """counts (h,) int64 = the set (1) cells of each row of mask (h, w) uint8 0 / 1."""
    h, w = mask.shape
    for pr in prange(h):
        y = np.int64(pr)
        mr = mask[y]
        n = np.int64(0)
        for x in range(w):
            n += np.int64(mr[x])
        counts[y] = n


@njit(cache=True, nogil=True)
def splat_fill_sparse_kernel(px, py, sc, dn, sel, h, w, buf, pc, lc, ld, lv):
    """splat_min_kernel then layer_fill_kernel for few used fragments (sel: their flat
    indices in the fragment grid, ascending; a background layer's cases are a few percent
    of a frame), serially: each fragment's target cell (splat_min_kernel's arithmetic)
    first marks its cell of buf (h * w int64; the other cells are never read), then keeps
    the least key there (float32 bits of the sanitised depth << 32 | flat source index,
    unique), then the fragment whose key is its cell's fills the cell where the layer (lc,
    ld, lv) has no valid fragment yet. The same winners, so the same layer, as the dense
    pair of kernels, without their passes over every cell (2 x 16 MB of buffers and 24 MB
    of results per 1080p call)."""
    ws = dn.shape[1]
    hm1 = F32(h - 1)
    wm1 = F32(w - 1)
    wf = F32(w)
    hf = F32(h)
    n = sel.shape[0]
    qs = np.empty(n, dtype=np.int64)
    ks = np.empty(n, dtype=np.int64)
    for i in range(n):
        s = sel[i]
        y = s // ws
        x = s - y * ws
        tx = np.floor(px[y, x] / sc)
        ty = np.floor(py[y, x] / sc)
        d = dn[y, x]
        d = INF if d != d else d
        d = ZERO if d < ZERO else d  # clamp_min(0) (-inf too)
        inside = (tx >= ZERO) & (tx < wf) & (ty >= ZERO) & (ty < hf)
        q = f2i64(clamp_b(ty, ZERO, hm1) * wf + clamp_b(tx, ZERO, wm1))
        qs[i] = q if inside else np.int64(-1)
        ks[i] = (np.int64(np.float32(d).view(np.int32)) << 32) | s
        if inside:
            buf[q] = I64_MAX
    for i in range(n):
        q = qs[i]
        if q >= 0 and ks[i] < buf[q]:
            buf[q] = ks[i]
    pcf = pc.reshape((3, pc.shape[1] * pc.shape[2]))  # (flat: the source index)
    for i in range(n):
        q = qs[i]
        if q < 0 or ks[i] != buf[q]:
            continue
        cy = q // w
        cx = q - cy * w
        if lv[cy, cx] != U0:
            continue
        s = sel[i]
        for k in range(3):
            lc[k, cy, cx] = pcf[k, s]
        ld[cy, cx] = np.int32(ks[i] >> 32).view(np.float32)
        lv[cy, cx] = np.uint8(1)


@njit(**KERNEL)
def layer_fill_kernel(src, dep, pc, lc, ld, lv):
    """A splat's winners into a layer, in place: cells without a valid fragment whose
    splat has a winner take its colour (pc at the flat source index), depth, validity."""
    h, w = src.shape
    pcf = pc.reshape((3, pc.shape[1] * pc.shape[2]))  # (flat: the source index)
    for pr in prange(h):
        y = np.int64(pr)
        for x in range(w):
            s = src[y, x]
            f = (s >= 0) & (lv[y, x] == U0)
            sc = max(s, np.int64(0))
            for k in range(3):
                lc[k, y, x] = pcf[k, sc] if f else lc[k, y, x]
            ld[y, x] = dep[y, x] if f else ld[y, x]
            lv[y, x] = np.uint8(1) if (f | (lv[y, x] != U0)) else U0
