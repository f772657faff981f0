"""numba kernels (fgcli.kernels) against their torch reference (fgcli.ops and
fgcli.kernels.reference): random inputs, the docs/design.md section 5 hard cases, whole
pipelines with --backend numba vs torch, the dispatch, and the CLI switch.

Exactness: each op's contract (fgcli.kernels.contract.CONTRACTS) says what must be equal
on every CPU (decisions: masks, holes, integer vectors, keys, NaN / inf positions) and how
close its floats must be (torch's vector kernels fuse some products that its plain ones
round on their own). The comparisons below apply it, so they pass under any
ATEN_CPU_CAPABILITY. Bit-for-bit checks remain where the contract is exact (integer
arithmetic, correctly rounded float32 operations in the reference's order) and between two
runs of the kernels themselves (in place or not, two threads or one, fused or not).
"""
from __future__ import annotations

import contextlib
import math
import os
import subprocess
import sys

import numpy as np
import pytest
import torch

pytest.importorskip("numba")

from fgcli import ops as R  # noqa: E402
from fgcli.kernels import op, reference as RF, resolve  # noqa: E402
from fgcli.kernels import ops as K  # noqa: E402
from fgcli.kernels.contract import CONTRACTS, EXACT, PIPELINE, Contract, check  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
INF, NAN = float("inf"), float("nan")
C = CONTRACTS
# a pipeline's frames as written (half floats): PIPELINE's differences may round to
# neighbouring binary16 values, one half ulp apart (2**-10 relative)
HALF_OUTPUT = Contract(ulp=1 << 13, rel=2.0 ** -10, why="PIPELINE, rounded to binary16")


def same(name, a, b, contract=EXACT, unsure=None):
    """a (the kernel's) agrees with b (the reference's) under ``contract`` (exact by
    default); unsure: elements excluded (the reference's decision within the bound of its
    threshold there)."""
    check(name, a, b, contract, unsure)


same_result = same


def zero_signs_alike(name, a, b):
    """Where the reference holds a zero, the kernel holds a zero of the same sign."""
    z = b == 0
    assert bool((a[z] == 0).all()) and torch.equal(a[z].signbit(), b[z].signbit()), name


def test_every_kernel_op_declares_a_contract():
    from fgcli.kernels import KERNEL_OPS

    assert set(KERNEL_OPS) <= set(CONTRACTS), set(KERNEL_OPS) - set(CONTRACTS)
    assert all(c.why for c in CONTRACTS.values())


def test_the_contract_check_fails_where_it_should():
    """Decisions exact, NaN / inf where the reference has them, floats within the bound
    (per channel), unsure elements excluded, exact contracts value for value."""
    from fgcli.kernels.contract import BILINEAR, LERP

    ref = torch.tensor([[[1.0, 2.0, INF, NAN]], [[1e-3, 5.0, -1.0, 0.0]]])
    ok = ref.clone()
    ok[0, 0, 0] = torch.nextafter(ref[0, 0, 0], torch.tensor(9.0))  # 1 ulp
    ok[1, 0, 3] = 1e-4  # within rel x the channel's range (5.0)
    check("bound", ok, ref, BILINEAR)
    for i, v in ((0, 1.01), (2, -INF), (3, 0.0)):  # beyond the bound; inf / NaN moved
        bad = ref.clone()
        bad[0, 0, i] = v
        with pytest.raises(AssertionError):
            check("moved", bad, ref, BILINEAR)
    with pytest.raises(AssertionError):
        check("2 ulp", ok * (1 + 2 ** -22), ref, LERP)
    bad = ref.clone()
    bad[0, 0, 0] = 3.0
    check("unsure", bad, ref, BILINEAR, unsure=torch.tensor([[True, False, False, False]]))
    with pytest.raises(AssertionError):
        check("exact", ok, ref, EXACT)
    with pytest.raises(AssertionError):  # a decision
        check("mask", torch.tensor([True, False]), torch.tensor([True, True]), BILINEAR)
    check("tree", (ref, None, {"a": ref > 1}), (ref.clone(), None, {"a": ref > 1}), EXACT)


# ----------------------------------------------------------------------------- inputs

def random_frames(h, w, seed=0, mv_scale=4.0):
    g = torch.Generator().manual_seed(seed)
    r = lambda *s: torch.rand(*s, generator=g)  # noqa: E731
    d1, d0 = r(1, h, w) * 50 + 1, r(1, h, w) * 50 + 1
    d1[:, : max(1, h // 5)] = INF
    d0[:, : max(1, h // 6)] = INF
    mv1 = torch.randn(2, h, w, generator=g) * mv_scale
    mv0 = torch.randn(2, h, w, generator=g) * mv_scale
    return {"c0": r(3, h, w) * 2, "c1": r(3, h, w) * 2, "d0": d0, "d1": d1, "mv0": mv0,
            "mv1": mv1}


def hard_cases():
    """docs/design.md section 5: (name, frames)."""
    out = [("random 37x53", random_frames(37, 53)), ("1x1", random_frames(1, 1, 1)),
           ("1xN", random_frames(1, 17, 2)), ("Nx1", random_frames(13, 1, 3)),
           ("odd 7x13", random_frames(7, 13, 4)), ("fast 24x40", random_frames(24, 40, 5, 30.0))]
    f = random_frames(16, 24, 6)
    f["mv0"].zero_()
    f["mv1"].zero_()
    out.append(("zero motion", f))
    f = random_frames(16, 24, 7)
    f["d1"][0, ::3, ::2] = 0.0
    f["d1"][0, 1::4] = -3.0
    f["d1"][0, 2, :5] = NAN
    f["d0"][0, ::2, ::3] = 0.0
    f["d0"][0, 3, :] = NAN
    out.append(("depth 0 / negative / NaN / inf", f))
    f = random_frames(16, 24, 8)
    f["mv1"][0, :4] = 1e9
    f["mv1"][1, 4:8] = -INF
    f["mv1"][0, 8:10] = NAN
    f["mv0"][1, :, :6] = INF
    f["mv0"][0, 10:] = 3e7
    out.append(("huge / inf / NaN vectors", f))
    f = random_frames(15, 21, 9)
    yy, xx = torch.meshgrid(torch.arange(15.0), torch.arange(21.0), indexing="ij")
    f["mv1"] = torch.stack([10.0 - xx, 7.0 - yy])  # every pixel lands on (10, 7)
    f["mv0"] = f["mv1"].clone()
    f["d1"] = torch.full((1, 15, 21), 5.0)  # and all at the same depth: index ties
    out.append(("all pixels into one", f))
    f = random_frames(16, 24, 10)
    f["c0"][0] = 65504.0
    f["c1"][1, ::2] = 65504.0
    f["c0"][2, 1::2] = 1e-7
    f["c1"][:, 3, :4] = NAN
    f["c0"][:, 5, :3] = INF
    f["c1"][:, 6, 2:6] = -INF
    out.append(("HDR / NaN / inf colour", f))
    f = random_frames(24, 40, 11)
    g = torch.Generator().manual_seed(12)
    # static rows (each source onto its own pixel after the 3x3 dilation: zero, -0 and
    # sub-pixel vectors) that near sources of moving rows land in, from rows before them
    # (written first within a band) and after; sky, far and NaN depths in the static rows
    mv = torch.zeros(2, 24, 40)
    mv[1, 2::8] = torch.where(torch.arange(40) % 2 == 0, 5.0, -5.0)  # (down / up ~2 rows)
    mv[0, 2::8] = torch.randn(3, 40, generator=g) * 0.5
    mv[0, 6::8] = -0.0
    mv[:, 5::8] = 0.2
    f["mv1"], f["mv0"] = mv, mv.clone()
    f["d1"] = 40.0 + torch.rand(1, 24, 40, generator=g) * 10.0
    f["d1"][0, 2::8] = 0.5 + torch.rand(3, 40, generator=g) * 0.1
    f["d1"][0, 4::8, ::3] = INF
    f["d1"][0, 7, 5] = NAN
    out.append(("static rows", f))
    return out


CASES = hard_cases()
IDS = [c[0] for c in CASES]


# ----------------------------------------------------------------------------- per kernel

@pytest.mark.parametrize("name,f", CASES, ids=IDS)
def test_dilate(name, f):
    for r in (0, 1, 2):
        same_result(f"dilate r{r}", K.dilate_nearest_depth(f["d1"], f["mv1"], r),
                    R.dilate_nearest_depth(f["d1"], f["mv1"], r))


SPLATS = [dict(model="quadratic", mode="interp", alpha=0.37),
          dict(model="quadratic", mode="interp", alpha=0.5, depth0=True),
          dict(model="linear", mode="interp", alpha=0.0),
          dict(model="quadratic", mode="interp", alpha=1.0),
          dict(model="linear", mode="extrap", alpha=0.5),
          dict(model="quadratic", mode="extrap", alpha=2.5),
          dict(model="quadratic", mode="interp", alpha=0.3, no_mv0=True)]


def _splats(f):
    dd, mm = R.dilate_nearest_depth(f["d1"], f["mv1"])
    for kw in SPLATS:
        kw = dict(kw)
        a = kw.pop("alpha")
        d0 = f["d0"] if kw.pop("depth0", False) else None
        mv0 = None if kw.pop("no_mv0", False) else f["mv0"]
        yield (f"splat {kw} a={a} d0={d0 is not None}", dd, mm, mv0, a, kw, d0)


@pytest.mark.parametrize("name,f", CASES, ids=IDS)
def test_splat_gap_fill_and_extrap_fill(name, f):
    for label, dd, mm, mv0, a, kw, d0 in _splats(f):
        rk = K.splat_motion(dd, mm, mv0, a, depth0=d0, **kw)
        rr = R.splat_motion(dd, mm, mv0, a, depth0=d0, **kw)
        same_result(label, rk, rr, C["splat_motion"])
        for thr in (0.01, 0.0, 1.0):
            same_result(f"{label} gap_fill {thr}", K.gap_fill(rr, thr),
                        R.gap_fill(rr, thr))
        same_result(f"{label} gap_fill fallback", K.gap_fill(rr, 0.01, "nearest", f["mv0"], f["d0"]),
                    R.gap_fill(rr, 0.01, "nearest", f["mv0"], f["d0"]))
        same_result(f"{label} gap_fill fallback mv", K.gap_fill(rr, 0.01, "nearest", f["mv1"]),
                    R.gap_fill(rr, 0.01, "nearest", f["mv1"]))
        if rr.mode == "extrap":
            g = R.gap_fill(rr)
            for thr in (1e-3, 0.5):
                same_result(f"{label} extrap_fill", K.fill_extrap_holes(g, f["mv1"], dd, thr),
                            R.fill_extrap_holes(g, f["mv1"], dd, thr))


def test_gap_fill_on_crack_fields():
    """The 2x2-block rule on fields full of cracks and holes: two depth layers at random
    (every 3x3 pattern of nearer / farther / empty occurs), sky, NaN and zero depths, edge
    pixels; the kernel decides every pixel with selects and picks candidates in a second
    pass, the reference per pixel."""
    g = torch.Generator().manual_seed(11)
    for h, w in ((7, 9), (33, 40)):
        near = torch.rand(1, h, w, generator=g) < 0.5
        depth = torch.where(near, 1.0 + torch.rand(1, h, w, generator=g) * 0.005,
                            5.0 + torch.rand(1, h, w, generator=g))
        depth[0, 0, 1], depth[0, 2, 3], depth[0, -1, -1] = INF, NAN, 0.0
        valid = torch.rand(1, h, w, generator=g) < 0.7
        to1 = torch.randn(2, h, w, generator=g)
        r = R.SplatResult(to1=to1, to0=-to1 * 0.5, depth=depth, valid=valid,
                          source=torch.arange(h * w, dtype=torch.int32).view(1, h, w),
                          alpha=0.5, mode="interp")
        fb = torch.randn(2, h, w, generator=g)
        for thr in (0.0, 0.01, 0.5, 1.0):
            same_result(f"{h}x{w} thr {thr}", K.gap_fill(r, thr), R.gap_fill(r, thr))
            same_result(f"{h}x{w} thr {thr} fb", K.gap_fill(r, thr, "nearest", fb, depth),
                        R.gap_fill(r, thr, "nearest", fb, depth))


def _scratch_copy(r):
    """A scratch SplatResult with planes of its own (what splat_motion's kernel returns)."""
    return r.replace(**{k: (None if getattr(r, k) is None else getattr(r, k).clone())
                        for k in ("to1", "to0", "depth", "valid", "source")}, scratch=True)


def _planes(r):
    return [None if t is None else t.clone() for t in (r.to1, r.to0, r.depth, r.valid,
                                                          r.source)]


@pytest.mark.parametrize("name,f", CASES, ids=IDS)
def test_in_place_refinements_match_the_reference(name, f):
    """gap_fill / fill_extrap_holes with in_place=True write into a scratch result's
    planes (the kernels' own, fresh splat output) with the reference's result, and spend
    it; a result that is not scratch is never written to."""
    for label, dd, mm, mv0, a, kw, d0 in _splats(f):
        r = K.splat_motion(dd, mm, mv0, a, depth0=d0, **kw)
        assert r.scratch, label
        fb = [(None, None), (f["mv0"], f["d0"]), (f["mv1"], None)]
        for thr in (0.01, 0.0, 1.0):
            for fmv, fd in fb:
                want = R.gap_fill(r, thr, "nearest", fmv, fd)
                src = _scratch_copy(r)
                got = K.gap_fill(src, thr, "nearest", fmv, fd, in_place=True)
                same_result(f"{label} gap_fill {thr} in place", got, want)
                assert got.to1.data_ptr() == src.to1.data_ptr(), label  # no copy made
                assert got.scratch and not src.scratch, label
                # a spent (or any non-scratch) result is read, never written
                before = _planes(src)
                again = K.gap_fill(src, thr, "nearest", fmv, fd, in_place=True)
                for x, y in zip(before, _planes(src)):
                    assert (x is None and y is None) or torch.equal(x, y), label
                assert again.to1.data_ptr() != src.to1.data_ptr(), label
        if r.mode == "extrap":
            g = R.gap_fill(r)
            for thr in (1e-3, 0.5):
                want = R.fill_extrap_holes(g, f["mv1"], dd, thr)
                src = _scratch_copy(g)
                got = K.fill_extrap_holes(src, f["mv1"], dd, thr, in_place=True)
                same_result(f"{label} extrap_fill {thr} in place", got, want)
                assert got.to1.data_ptr() == src.to1.data_ptr() and not src.scratch, label


def test_in_place_gap_fill_cleans_an_unclean_depth_plane():
    """A scratch result whose depth is not sanitised (NaN, negative and finite values at
    holes: not what the splat writes, but what a caller may hand in) comes out as the
    reference's, through the in-place kernels' row-cleaning pass."""
    g = torch.Generator().manual_seed(5)
    for h, w in ((6, 7), (31, 45)):
        depth = 1.0 + torch.rand(1, h, w, generator=g) * 3
        depth[0, 1, 2], depth[0, 3, 4], depth[0, -1, 0] = NAN, -2.0, INF
        valid = torch.rand(1, h, w, generator=g) < 0.8
        to1 = torch.randn(2, h, w, generator=g)
        for mode in ("interp", "extrap"):
            r = R.SplatResult(to1=to1, to0=-to1 * 0.5, depth=depth, valid=valid,
                              source=torch.arange(h * w, dtype=torch.int32).view(1, h, w),
                              alpha=0.5, mode=mode)
            want = R.gap_fill(r, 0.01)
            got = K.gap_fill(_scratch_copy(r), 0.01, in_place=True)
            same_result(f"{h}x{w} {mode}", got, want)
            if mode == "extrap":
                mv1 = torch.randn(2, h, w, generator=g) * 3
                e = R.SplatResult(to1=to1, to0=None, depth=depth, valid=valid,
                                  source=r.source, alpha=0.5, mode=mode)
                same_result(f"{h}x{w} extrap_fill",
                            K.fill_extrap_holes(_scratch_copy(e), mv1, depth, in_place=True),
                            R.fill_extrap_holes(e, mv1, depth))


@pytest.mark.parametrize("name,f", CASES[:3], ids=IDS[:3])
def test_splat_without_offsets_toward_frame0(name, f):
    """splat_motion(toward0=False) (extrapolation: no stage samples frame 0) leaves to0
    out and changes nothing else, through gap_fill and fill_extrap_holes; the kernels
    (which then neither write nor copy it) agree with the reference, and so does the
    reference's dense (GPU) path."""
    dd, mm = R.dilate_nearest_depth(f["d1"], f["mv1"])
    for mode, a, mv0 in (("extrap", 0.5, None), ("extrap", 2.0, f["mv0"]), ("interp", 0.3, f["mv0"])):
        full = R.splat_motion(dd, mm, mv0, a, mode=mode)
        part = R.splat_motion(dd, mm, mv0, a, mode=mode, toward0=False)
        assert part.to0 is None
        same_result(f"{mode} kernel splat", K.splat_motion(dd, mm, mv0, a, mode=mode,
                                                          toward0=False), part,
                    C["splat_motion"])
        stages = [("gap_fill", lambda r: R.gap_fill(r, 0.01), lambda r: K.gap_fill(r, 0.01)),
                  ("gap_fill mean", lambda r: R.gap_fill(r, 0.01, "mean"), None),
                  ("gap_fill fallback", lambda r: R.gap_fill(r, 0.01, "nearest", f["mv0"], f["d0"]),
                   lambda r: K.gap_fill(r, 0.01, "nearest", f["mv0"], f["d0"]))]
        for label, ref, ker in stages:
            g_full, g_part = ref(full), ref(part)
            assert g_part.to0 is None
            same_result(f"{mode} {label}", g_part, g_full.replace(to0=None))
            if ker is not None:
                same_result(f"{mode} {label} kernel", ker(part), g_part)
            with dense():
                same_result(f"{mode} {label} dense", ref(part), g_part)
        if mode == "extrap":
            g_full, g_part = R.gap_fill(full), R.gap_fill(part)
            e_full = R.fill_extrap_holes(g_full, f["mv1"], dd)
            e_part = R.fill_extrap_holes(g_part, f["mv1"], dd)
            same_result("extrap_fill", e_part, e_full.replace(to0=None))
            same_result("extrap_fill kernel", K.fill_extrap_holes(g_part, f["mv1"], dd), e_part)
            with dense():
                same_result("extrap_fill dense", R.fill_extrap_holes(g_part, f["mv1"], dd),
                            e_part)
        else:
            with pytest.raises(ValueError, match="to0"):
                R.generated_mv(part)
    # batched
    b = R.splat_motion(torch.stack([dd, dd]), torch.stack([mm, mm]), None, 0.5, mode="extrap",
                       toward0=False)
    assert b.to0 is None and R.gap_fill(b).to0 is None


@contextlib.contextmanager
def dense():
    """The reference ops' GPU (dense, no read-back) paths, on the CPU
    (fgcli.ops._util.FORCE_DENSE; tests/test_dense_paths.py uses it too)."""
    from fgcli.ops import _util

    old = _util.FORCE_DENSE
    _util.FORCE_DENSE = True
    try:
        yield
    finally:
        _util.FORCE_DENSE = old


def test_fallbacks_to_the_reference():
    """Variants without a kernel run the reference (same results by construction)."""
    f = CASES[0][1]
    r = R.splat_motion(f["d1"], f["mv1"], f["mv0"], 0.5)
    same_result("mean fill", K.gap_fill(r, fill="mean"), R.gap_fill(r, fill="mean"))
    same_result("catmull-rom", K.warp_frames(f["c1"], f["d1"], r.to1, mode="catmull-rom"),
                RF.warp_frames(f["c1"], f["d1"], r.to1, mode="catmull-rom"))
    same_result("batched dilate", K.dilate_nearest_depth(f["d1"][None], f["mv1"][None]),
                R.dilate_nearest_depth(f["d1"][None], f["mv1"][None]))


@pytest.mark.parametrize("name,f", CASES, ids=IDS)
def test_warp_frames(name, f):
    dd, mm = R.dilate_nearest_depth(f["d1"], f["mv1"])
    r = R.gap_fill(R.splat_motion(dd, mm, f["mv0"], 0.4), fallback_mv=f["mv0"],
                   fallback_depth=f["d0"])
    same_result("warp two", K.warp_frames(f["c1"], f["d1"], r.to1, f["c0"], f["d0"], r.to0),
                RF.warp_frames(f["c1"], f["d1"], r.to1, f["c0"], f["d0"], r.to0),
                C["warp_frames"])
    # raw, unsanitised offsets (NaN, inf, huge) straight from the vectors
    same_result("warp one, raw flow", K.warp_frames(f["c1"], f["d1"], f["mv1"]),
                RF.warp_frames(f["c1"], f["d1"], f["mv1"]), C["warp_frames"])


@pytest.mark.parametrize("name,f", CASES, ids=IDS)
def test_mv_warp(name, f):
    for mv, scale, raw in ((f["mv1"], 0.37, True), (f["mv1"], -0.63, True),
                           (f["mv0"], 0.5, False), (f["mv1"], 2.0, True)):
        same_result(f"mv_warp {scale}", K.mv_warp(f["c1"], f["d1"], mv, scale, raw_depth_flow=raw),
                    RF.mv_warp(f["c1"], f["d1"], mv, scale, raw_depth_flow=raw), C["mv_warp"])


def _near_threshold(c0, c1, t_b):
    """Pixels whose brightness difference is within 1e-5 of t_b (see the module doc)."""
    b = R.brightness_difference(R.sanitize_values(c0), R.sanitize_values(c1))
    return (b - t_b).abs() < 1e-5


@pytest.mark.parametrize("name,f", CASES, ids=IDS)
def test_blend(name, f):
    dd, mm = R.dilate_nearest_depth(f["d1"], f["mv1"])
    r = R.gap_fill(R.splat_motion(dd, mm, f["mv0"], 0.4), fallback_mv=f["mv0"],
                   fallback_depth=f["d0"])
    s1, v1, sd1, s0, v0, sd0 = RF.warp_frames(f["c1"], f["d1"], r.to1, f["c0"], f["d0"], r.to0)
    # some pixels with equal colours, some static (zero offsets)
    s1[:, ::5] = s0[:, ::5]
    r.to1[:, 1::4] = 0.0
    r.to0[:, 1::4] = 0.0
    skip = _near_threshold(s0, s1, 0.13)
    for a in (0.0, 0.3, 0.5, 0.7, 1.0):
        for dt in (None, r.depth):
            for st in (None, r):
                ck, dk = K.blend_eq1(s0, s1, sd0, sd1, v0, v1, dt, a, 0.02, 0.13, st)
                cr, dr = RF.blend_eq1(s0, s1, sd0, sd1, v0, v1, dt, a, 0.02, 0.13, st)
                same(f"blend a={a} color", ck, cr, C["blend_eq1"], skip)
                same(f"blend a={a} depth", dk, dr, C["blend_eq1"], skip)
    # the op-level signature with a given static mask, and colour only
    st = RF.static_mask(r)
    same("blend_interp static", K.blend_interp(s0, s1, sd0, sd1, v0, v1, alpha=0.3, static=st),
         R.blend_interp(s0, s1, sd0, sd1, v0, v1, alpha=0.3, static=st), C["blend_interp"], skip)


@pytest.mark.parametrize("name,f", CASES, ids=IDS)
def test_crossfade(name, f):
    for a, ms in ((0.0, 0.0), (0.37, 0.37), (0.5, 0.25), (1.0, 0.5)):
        same_result(f"crossfade {a}", K.crossfade(f["c0"], f["c1"], f["d0"], f["d1"], f["mv1"], a, ms),
                    RF.crossfade(f["c0"], f["c1"], f["d0"], f["d1"], f["mv1"], a, ms),
                    C["crossfade"])


def test_outputs_are_finite_on_hard_cases():
    for name, f in CASES:
        dd, mm = K.dilate_nearest_depth(f["d1"], f["mv1"])
        r = K.gap_fill(K.splat_motion(dd, mm, f["mv0"], 0.5), fallback_mv=f["mv0"])
        s1, v1, sd1, s0, v0, sd0 = K.warp_frames(f["c1"], f["d1"], r.to1, f["c0"], f["d0"], r.to0)
        c, d = K.blend_eq1(s0, s1, sd0, sd1, v0, v1, None, 0.5, 0.02, 0.13, r)
        assert bool(torch.isfinite(c).all()), name
        assert not bool(torch.isnan(d).any()), name


# ----------------------------------------------------------------------------- pipelines

def _pipeline_outputs(name, mode, backend, f, alpha):
    from fgcli import pipeline as pl
    from fgcli.frame import Frame
    from fgcli.pipeline import run_stages
    from fgcli.runner import make_ctx

    fr = [Frame(number=n, color=f[f"c{n}"], depth=f[f"d{n}"], mv=f[f"mv{n}"]) for n in (0, 1)]
    ctx = make_ctx(fr[0], fr[1], alpha, mode)
    ctx.update(prev_time=0.0, state=None, backend=backend, scene_cuts="off")
    with torch.inference_mode():
        out = run_stages(pl.load(name).build(mode), ctx)
    return out["color"], out["depth"], out["mv"]


@pytest.mark.parametrize("name,mode", [("mob-fgsr", "interp"), ("mob-fgsr", "extrap"),
                                       ("mv-warp", "interp"), ("mv-warp", "extrap"),
                                       ("blend", "interp"), ("repeat", "interp"),
                                       ("mv-interp", "interp"), ("fsr3-interp", "interp")])
def test_pipelines_numba_equals_torch(name, mode, tiny_scene):
    s0, s1 = tiny_scene(0), tiny_scene(1)
    f = {f"{k}{i}": torch.from_numpy(s[key]) for i, s in ((0, s0), (1, s1))
         for k, key in (("c", "color"), ("d", "depth"), ("mv", "mv"))}
    for alpha in ((0.25, 0.5, 0.75) if mode == "interp" else (0.5,)):
        c_n, d_n, m_n = _pipeline_outputs(name, mode, "numba", f, alpha)
        c_t, d_t, m_t = _pipeline_outputs(name, mode, "torch", f, alpha)
        same(f"{name} color", c_n, c_t, PIPELINE)
        same(f"{name} depth", d_n, d_t, PIPELINE)
        same(f"{name} mv", m_n, m_t, PIPELINE)


@pytest.mark.parametrize("h,w,levels,block,search,median", [
    (72, 128, 7, 8, 8, True),     # FSR 3's settings (sixteen offsets at a time)
    (37, 53, 3, 8, 8, False),     # partial blocks at the right and bottom edges
    (50, 70, 4, 5, 3, True),      # other block and search sizes (the generic loop)
    (1, 1, 7, 8, 8, True),        # one pixel
    (9, 300, 7, 8, 2, True),      # wide and flat: a single level
    (544, 960, 7, 8, 8, True),    # levels large enough for the chain's parallel loops
])
def test_block_flow(h, w, levels, block, search, median):
    """The block search is integer arithmetic: equal to the reference exactly, on any CPU
    (large shifts that need the pyramid, noise, flat regions where ties decide, edges)."""
    from fgcli.ops import fsr3

    g = torch.Generator().manual_seed(h * 1000 + w)
    base = torch.rand(1, 1, h + 40, w + 40, generator=g)
    base = torch.nn.functional.avg_pool2d(base, 5, 1, 2)[0] * 255.0
    l0 = base[:, 10:10 + h, 10:10 + w].round()
    l1 = (base[:, 13:13 + h, 4:4 + w] + torch.randint(-4, 5, (1, h, w), generator=g)).clamp(0, 255)
    l1[:, : h // 3, : w // 3] = 128.0  # a flat region: every offset ties
    # stripes of period 2 shifted by one: offsets -1 and +1 give the same SAD at the same
    # distance, so the tie rule (first offset in (dy, dx) order) decides
    stripes = (torch.arange(w) % 2 * 255.0).expand(1, h, w).contiguous()
    # raw values: fractions (.5 rounds to even), out of range, NaN, +-inf (the levels'
    # sanitising and rounding, and the pyramid's averages of odd sums)
    raw = base[:, 10:10 + h, 10:10 + w] * 1.3 - 20.0
    raw.view(-1)[::7] = torch.arange(raw.view(-1)[::7].numel()) * 0.5 % 256
    raw.view(-1)[3::11] = NAN
    raw.view(-1)[5::13] = INF
    raw.view(-1)[6::17] = -INF
    for a, b in ((l0, l1.round()), (l0, l0), (torch.zeros_like(l0), torch.full_like(l0, 255.0)),
                 (stripes, stripes.roll(1, -1)), (raw, l1), (l1, raw)):
        ref = fsr3.block_flow(a, b, levels, block, search, median)
        assert torch.equal(K.block_flow(a, b, levels, block, search, median), ref)
    # bytes in (luma8_u8's): the same vectors as their float values, on both backends
    a8 = l0.clamp(0, 255).to(torch.uint8)
    b8 = l1.round().clamp(0, 255).to(torch.uint8)
    ref = fsr3.block_flow(a8.float(), b8.float(), levels, block, search, median)
    assert torch.equal(fsr3.block_flow(a8, b8, levels, block, search, median), ref)
    assert torch.equal(K.block_flow(a8, b8, levels, block, search, median), ref)
    # the sub-pixel option runs the reference's refinement after the kernel's search
    ref = fsr3.block_flow(l0, l1.round(), levels, block, max(search, 2), median, True)
    assert torch.equal(K.block_flow(l0, l1.round(), levels, block, max(search, 2), median,
                                    True), ref)


def test_vector_median_is_the_references():
    """The 3x3 vector median of the block search (numba) against the torch reference on
    integer fields: edges, large vectors (where the centre's 1e-3 vanishes in float32 and
    the first of equal sums wins), all-equal fields, one block."""
    from fgcli.ops import fsr3

    g = torch.Generator().manual_seed(12)
    for h, w in ((1, 1), (1, 7), (5, 1), (4, 2), (2, 3), (17, 30), (135, 240)):
        for scale in (2, 9, 3000):
            f = torch.randint(-scale, scale + 1, (2, h, w), generator=g).float()
            assert torch.equal(K._median3(f), fsr3._vector_median3(f)), (h, w, scale)
        z = torch.zeros(2, h, w)
        assert torch.equal(K._median3(z), fsr3._vector_median3(z))
        # few values: many equal sums, the tie rule decides; sums of 2**15..2**17, where
        # float32 loses the centre's 1e-3 (but would keep a 1e-2)
        for step in (4000.0, 1500.0, 3000.0):
            t = torch.randint(-1, 2, (2, h, w), generator=g).float() * step
            assert torch.equal(K._median3(t), fsr3._vector_median3(t)), (h, w, step)


def test_mpsadbw_block_search_equals_the_portable_kernel(monkeypatch):
    """On x86 the 8x8 / -8..7 search sums its SADs with SSE4.1 mpsadbw (exact integers):
    the same vectors as the portable float kernel, for predictions that push the window
    past every edge, on noise, flat and striped images; and the intrinsic's least key
    equals numpy's brute force."""
    import numpy as np

    from fgcli.kernels._intrin import HAVE_MPSADBW
    from fgcli.kernels.flow import block_search_kernel, block_search_sad_kernel

    if not HAVE_MPSADBW:
        pytest.skip("no SSE4.1 (the portable kernel runs instead)")
    from numba import njit

    from fgcli.kernels._intrin import sad_search8, sad_search8_sse41
    from fgcli.kernels.flow import _ORDER

    @njit
    def search(win, cur, cst):
        return sad_search8(win, 0, 24, cur, 0, cst, _ORDER)

    @njit
    def search_sse41(win, cur, cst):
        return sad_search8_sse41(win, 0, 24, cur, 0, cst, _ORDER)

    rng = np.random.default_rng(4)
    for i in range(40):  # the least key against a brute force over the 256 offsets
        win = rng.integers(0, 256, 23 * 24 + 24, dtype=np.uint8)
        if i % 4 == 0:  # many equal SADs: the tie part decides
            win[:] = rng.integers(0, 2, win.size) * 255
        cst = 16 if i % 2 else 40  # the block's rows in a copy, or in place in a frame
        cur = rng.integers(0, 256, 8 * cst, dtype=np.uint8)
        if i % 4 == 0:
            cur[:] = rng.integers(0, 2, cur.size) * 255
        wv = win[:23 * 24].reshape(23, 24).astype(np.int64)
        cv = cur.reshape(8, cst)[:, :8].astype(np.int64)
        keys = [(int(np.abs(wv[dy:dy + 8, dx:dx + 8] - cv).sum()) << 14) |
                int(_ORDER[16 * dy + dx]) for dy in range(16) for dx in range(16)]
        assert search(win, cur, cst) == min(keys)
        assert search_sse41(win, cur, cst) == min(keys)  # (the same code without AVX2)
    for h, w in ((64, 96), (135, 240), (37, 53), (9, 7), (1, 30), (23, 24), (24, 40)):
        nby, nbx = -(-h // 8), -(-w // 8)
        noise = rng.integers(0, 256, (h, w)).astype(np.uint8)
        flat = np.full((h, w), 77, np.uint8)
        stripes = np.broadcast_to((np.arange(w) % 2 * 255).astype(np.uint8), (h, w)).copy()
        for cur, prev in ((noise, np.roll(noise, (2, -3), (0, 1))), (flat, flat),
                          (stripes, np.roll(stripes, 1, 1)), (noise, flat)):
            for pred in (np.zeros((2, nby, nbx), np.int64),
                         rng.integers(-40, 41, (2, nby, nbx)).astype(np.int64)):
                a = np.empty_like(pred)
                b = np.empty_like(pred)
                block_search_kernel(cur.astype(np.int32), prev.astype(np.int32), pred, 8, 8, a)
                block_search_sad_kernel(cur, prev, pred, b)
                assert np.array_equal(a, b), (h, w)


def _warp_window_cases(h, w, seed):
    """Flows for the warp's 16-lane fetches: smooth (windows of two and three rows),
    large random (gathered), zero (the exact case), past every edge, NaN / inf / huge."""
    g = torch.Generator().manual_seed(seed)
    yy, xx = torch.meshgrid(torch.arange(h, dtype=torch.float32),
                            torch.arange(w, dtype=torch.float32), indexing="ij")
    smooth = torch.stack([3.3 + 5 * torch.sin(yy * 0.05 + xx * 0.01),
                          -2.6 + 1.7 * torch.cos(xx * 0.043)])
    rough = torch.randn(2, h, w, generator=g) * 40.0
    edges = torch.stack([(xx - w / 2) * 0.3, (yy - h / 2) * 0.3])  # zoom: off-screen taps
    bad = smooth.clone()
    bad[0, ::7, ::5] = NAN
    bad[1, 1::6, ::3] = INF
    bad[0, 2::9] = -3e7
    zero = smooth.clone()
    zero[:, : h // 2, : w // 2] = 0.0
    return [smooth, rough, edges, bad, zero]


def test_warp_window_fetches_equal_the_gathers():
    """AVX-512 / AVX2: the mob-fgsr warp fetching its taps 16 pixels at a time from windows of
    source rows (fgcli.kernels._intrin.bilinear16x3, nearest16) gives the per-pixel
    gathering kernel's values bit for bit (and so the reference's): widths that are and
    are not a multiple of 16, narrower than the 32-column window, one and two rows; colour
    with NaN / +-inf / 65504 (the sanitising path) and NaN / inf depth; every fetch path
    taken (windows of two and three rows, gathers). The 3x3 dilation's and the splat
    resolve's reads at the winners (fetch16x2) against the reference on the same frames."""
    import numpy as np

    from fgcli.kernels._intrin import HAVE_WINDOW16
    from fgcli.kernels.ops import _grid
    from fgcli.kernels.warp import warp_pixels_kernel, warp_window_kernel

    if not HAVE_WINDOW16:
        pytest.skip("no AVX-512 or AVX2 (the gathering kernel runs instead)")
    for h, w in ((45, 96), (37, 53), (9, 40), (20, 17), (2, 70), (1, 33), (30, 31)):
        f = random_frames(h, w, h * w)
        f["c1"][0, ::5, ::3] = NAN
        f["c1"][1, 2::7] = INF
        f["c0"][2, :, ::4] = -INF
        f["c0"][1, 1::3] = 65504.0
        f["d1"][0, ::4, ::5] = NAN
        gxn, gyn, kx, ky = _grid(h, w)
        flows = _warp_window_cases(h, w, w)
        for i, to1 in enumerate(flows):
            to0 = flows[(i + 1) % len(flows)]
            outs = []
            for kern in (warp_pixels_kernel, warp_window_kernel):
                o = [np.full((3, h, w), 7.0, np.float32), np.full((h, w), 7.0, np.float32),
                     np.zeros((h, w), np.bool_)] * 2
                o = [a.copy() for a in o]
                kern(f["c1"].numpy(), f["d1"][0].numpy(), to1.numpy(), f["c0"].numpy(),
                     f["d0"][0].numpy(), to0.numpy(), True, gxn, gyn, kx, ky, *o)
                outs.append(o)
            for a, b in zip(*outs):
                assert np.array_equal(a.view(np.uint8), b.view(np.uint8)), (h, w, i)
        # the 3x3 dilation reads the winner's vector the same way (fetch16x2)
        mv = flows[1].clone()
        mv[0, ::3, ::4] = NAN
        mv[1, 1::5] = INF
        same_result(f"dilate {h}x{w}", K.dilate_nearest_depth(f["d1"], mv, 1),
                    R.dilate_nearest_depth(f["d1"], mv, 1))
        # and the splat's resolve its reads at the winning sources (fetch16x2)
        for model, mode, a, t0 in (("quadratic", "interp", 0.4, True),
                                   ("linear", "extrap", 0.5, False),
                                   ("linear", "interp", 0.7, True)):
            same_result(f"splat {h}x{w} {model}",
                        K.splat_motion(f["d1"], mv, flows[0], a, model, mode, toward0=t0),
                        R.splat_motion(f["d1"], mv, flows[0], a, model, mode, toward0=t0),
                        C["splat_motion"])


@pytest.mark.parametrize("name,f", CASES + [("wide 45x96", random_frames(45, 96, 11)),
                                            ("wide 37x53 fast", random_frames(37, 53, 12, 30.0))],
                         ids=IDS + ["wide 45x96", "wide 37x53 fast"])
def test_warp_blend_fused_equals_the_two_stages(name, f):
    """mob-fgsr's warp and blend in one pass (fgcli.kernels.ops.warp_blend, AVX-512 / AVX2) give
    the two stages' colour and depth bit for bit: every hard case, alpha inside and at both
    ends, with and without the target depth and the static cross-fade; elsewhere it
    declines (None) and the stages run one after the other."""
    from fgcli.kernels._intrin import HAVE_WINDOW16
    from fgcli.kernels.warp import flat_ok

    dd, mm = R.dilate_nearest_depth(f["d1"], f["mv1"])
    r = R.gap_fill(R.splat_motion(dd, mm, f["mv0"], 0.4), fallback_mv=f["mv0"],
                   fallback_depth=f["d0"])
    for a in (0.4, 0.0, 1.0, 0.7):
        for dt in (None, r.depth):
            for st in (None, r):
                args = (f["c1"], f["d1"], r.to1, f["c0"], f["d0"], r.to0, dt, a, 0.02, 0.13, st)
                got = K.warp_blend(*args)
                if not HAVE_WINDOW16 or not flat_ok(*f["d1"].shape[-2:], 3):
                    assert got is None
                    continue
                same_result(f"warp+blend a={a}", got, RF.warp_blend(*args), C["warp_blend"])
    assert K.warp_blend(f["c1"][:2], f["d1"], r.to1, f["c0"][:2], f["d0"], r.to0) is None


def test_mob_fgsr_runs_warp_and_blend_fused():
    """With the kernels the mob-fgsr interpolation times its warp and blend as one pass
    ("warp+blend") where the fused kernel applies, and the frame equals the torch run."""
    from fgcli import pipeline as pl
    from fgcli.kernels._intrin import HAVE_WINDOW16
    from fgcli.pipeline import Timings, run_stages
    from fgcli.runner import make_ctx
    from fgcli.synth import load_scene, render

    scene = load_scene(os.path.join(ROOT, "sample_data", "scenes", "blade.toml"), size=(96, 54))
    f0, f1 = render(scene, 3.0, 2.0, spp=1), render(scene, 4.0, 3.0, spp=1)
    outs = {}
    for backend in ("torch", "numba"):
        tm = Timings()
        ctx = make_ctx(f0, f1, 0.5, "interp")
        ctx.update(prev_time=0.0, state=None, backend=backend)
        with torch.inference_mode():
            outs[backend] = run_stages(pl.load("mob-fgsr").build("interp"), ctx, tm)
        fused = "warp+blend" in tm.stages
        assert fused == (backend == "numba" and HAVE_WINDOW16), tm.stages
        assert ("warp" in tm.stages) == (not fused)
    for k in ("color", "depth", "mv"):
        same(k, outs["numba"][k], outs["torch"][k], PIPELINE)


def test_window_fetch_intrinsics():
    """bilinear16x3, bilinear16x1 (each plane on its own), nearest16 and taps16 against a
    per-lane loop of the scalar helpers: random taps (gathered), taps within 32 columns of
    two and three rows (windows), the last column and row, NaN / +-inf / huge values
    (sanitised only in the planes that have them), zero-flow lanes and blocks of them;
    the returned fetch path covers all four. (AVX2 reads each half of 8 lanes from 16
    columns: the spread varies so that both fetches see windows and gathers.)"""
    import numpy as np
    from numba import njit

    from fgcli.kernels._common import INF as KINF, sval_b
    from fgcli.kernels._intrin import HAVE_WINDOW16, fma

    if not HAVE_WINDOW16:
        pytest.skip("no AVX-512 or AVX2")
    from fgcli.kernels._intrin import bilinear16x1, bilinear16x3, nearest16, taps16

    @njit
    def run(img, w, h, XA, XB, YA, YB, WT, Z, out, dout, cy, T):
        paths = np.zeros(XA.shape[0] // 16 * 2, np.int32)
        for b in range(XA.shape[0] // 16):
            t = taps16(img[1], np.int32(w), np.int32(h), XA, XB, YA, YB, np.int32(16 * b), T)
            p = bilinear16x3(img, np.int32(h * w), np.int32(w), np.int32(h), XA, XB, YA, YB, WT,
                             Z, np.int32(16 * b), np.int32(cy * w), out, np.int32(out.shape[1]),
                             np.int32(0))
            # (the same taps: the same path; 1, no fetch, where every lane's flow is zero)
            paths[2 * b] = p if (t == p) | (p == 1) else -1
            paths[2 * b + 1] = nearest16(img, np.int32(w), np.int32(h), XA, YA,
                                         np.int32(16 * b), dout, np.int32(0))
        return paths

    @njit
    def run1(img, w, h, XA, XB, YA, YB, WT, Z, out, cy):
        paths = np.zeros(XA.shape[0] // 16 * 3, np.int32)
        for k in range(3):
            for b in range(XA.shape[0] // 16):
                paths[3 * b + k] = bilinear16x1(img[k], np.int32(7), np.int32(w), np.int32(h),
                                                XA, XB, YA, YB, WT, Z, np.int32(16 * b),
                                                np.int32(cy * w), out[k], np.int32(7),
                                                np.int32(0))
        return paths

    @njit
    def ref(img, w, XA, XB, YA, YB, WT, Z, out, dout, cy):
        for x in range(XA.shape[0]):
            for k in range(3):
                t = [sval_b(img[k, YA[x], XA[x]]), sval_b(img[k, YA[x], XB[x]]),
                     sval_b(img[k, YB[x], XA[x]]), sval_b(img[k, YB[x], XB[x]])]
                r = fma(t[3], WT[3, x], fma(t[2], WT[2, x], fma(t[1], WT[1, x], t[0] * WT[0, x])))
                out[k, x] = sval_b(img[k, cy, x]) if Z[x] != 0 else r
            v = img[0, YA[x], XA[x]]
            dout[x] = KINF if v != v else v

    rng = np.random.default_rng(7)
    seen = set()
    for trial in range(120):
        h, w = (int(rng.integers(1, 9)), int(rng.integers(32, 90))) if trial % 5 else (5, 20)
        img = rng.standard_normal((3, h, w)).astype(np.float32) * 3
        if trial % 3 == 0:
            img[rng.integers(0, 3), rng.integers(0, h), rng.integers(0, w)] = np.nan
            img[rng.integers(0, 3), rng.integers(0, h), rng.integers(0, w)] = np.inf
            img[rng.integers(0, 3), rng.integers(0, h), rng.integers(0, w)] = -np.inf
            img[rng.integers(0, 3), rng.integers(0, h), rng.integers(0, w)] = 3e38
        n = 48
        kind = trial % 4
        if kind == 0:  # anywhere: gathered
            xa, ya = rng.integers(0, w, n), rng.integers(0, h, n)
        else:  # within ~28 (or ~12) columns of 1, 2 or 3 rows
            spread = 24 if trial % 2 else 8
            xa = np.clip(rng.integers(0, w) + rng.integers(-4, spread, n), 0, w - 1)
            ya = np.clip(rng.integers(0, h) + rng.integers(0, kind, n), 0, h - 1)
        xb, yb = np.minimum(xa + 1, w - 1), np.minimum(ya + 1, h - 1)
        XA, XB, YA, YB = (a.astype(np.int32) for a in (xa, xb, ya, yb))
        WT = rng.random((4, n)).astype(np.float32)
        WT[1, xb == xa] = 0.0
        WT[2, yb == ya] = 0.0
        WT[3, (xb == xa) | (yb == ya)] = 0.0
        Z = (rng.random(n) < 0.2).astype(np.int32)
        if trial % 7 == 0:  # a block of 16 zero-flow lanes: the centres only (path 1)
            Z[16:32] = 1
        cy = int(rng.integers(0, h))
        if w < n:  # the centre row read at lanes 0..n-1: a frame at least n wide
            continue
        a, b = np.full((3, n + 5), 9.0, np.float32), np.full((3, n + 5), 9.0, np.float32)
        da, db = np.zeros(n, np.float32), np.zeros(n, np.float32)
        T = np.full((4, n), 5.0, np.float32)
        pth = run(img, w, h, XA, XB, YA, YB, WT, Z, a, da, cy, T)
        seen.update(pth.tolist())
        allz = [bool(Z[16 * b:16 * b + 16].all()) for b in range(n // 16)]
        assert [p == 1 for p in pth[::2]] == allz, trial
        a1 = np.full((3, n + 5), 9.0, np.float32)
        pth1 = run1(img, w, h, XA, XB, YA, YB, WT, Z, a1, cy)
        assert np.array_equal(pth1.reshape(-1, 3), np.repeat(pth[::2, None], 3, 1)), trial
        ref(img, w, XA, XB, YA, YB, WT, Z, b, db, cy)
        assert np.array_equal(a1.view(np.int32), b.view(np.int32)), trial
        taps = np.stack([img[1, ya, xa], img[1, ya, xb], img[1, yb, xa], img[1, yb, xb]])
        assert np.array_equal(T.view(np.int32), taps.view(np.int32)), trial
        assert np.array_equal(a.view(np.int32), b.view(np.int32)), trial
        assert np.array_equal(da.view(np.int32), db.view(np.int32)), trial
    assert seen == {0, 1, 2, 3}, seen


def _fsr3_inputs(h, w, seed):
    g = torch.Generator().manual_seed(seed)
    c0, c1 = torch.rand(3, h, w, generator=g), torch.rand(3, h, w, generator=g)
    v = torch.randn(2, h, w, generator=g) * 4.0
    v[:, : h // 2] = torch.round(v[:, : h // 2])  # integer vectors: taps on texel centres
    d = torch.rand(1, h, w, generator=g) + 0.5
    if h >= 5:
        v[:, -2:] = 0.0  # static rows
        v[0, 1, : w // 2] = 1e9  # huge vectors (sanitised, clamped onto the ring)
        v[1, 2, :] = NAN
        v[0, 3, 0] = INF
        d[0, 0, :3] = INF  # sky
        d[0, 0, 3:5] = NAN
        d[0, 4, :2] = 0.0
        c0[0, 0, :2] = 1e30  # HDR, NaN and inf colour (the luminance agreement)
        c0[1, 1, :1] = NAN
        c1[2, 2, :3] = INF
        c1[:, 3, :2] = 0.0
    return c0, c1, v, d


def _tap_on_huge_value(c0, c1, v, of, a):
    """Pixels where a bilinear sample of the interpolation (either frame, game or flow
    vectors) lies within the rounding of its position (a few ulp of a coordinate) of a
    texel centre next to a huge or non-finite colour (|c| > 1e20). There one rounding of
    the position gives that tap weight 0 and another a few ulp, which times 1e30 decides
    the colour similarity and so the bias: a decision at its threshold (excluded)."""
    from fgcli.ops._util import sanitize_mv

    h, w = c0.shape[-2:]
    eps = 16 * 2.0 ** -23 * 2 * max(h, w)
    ys, xs = torch.meshgrid(torch.arange(h, dtype=torch.float64),
                            torch.arange(w, dtype=torch.float64), indexing="ij")
    out = torch.zeros(1, h, w, dtype=torch.bool)
    for c, s in ((c0, a), (c1, -(1.0 - a))):
        big = (~torch.isfinite(c) | (c.abs() > 1e20)).any(0, keepdim=True).float()
        big = torch.nn.functional.max_pool2d(big[None], 3, 1, 1)[0] > 0
        for f in (v, of):
            if f is None:
                continue
            f = sanitize_mv(f).double() * s
            px, py = xs + f[0], ys + f[1]
            near = ((px - px.round()).abs() <= eps) | ((py - py.round()).abs() <= eps)
            ix = px.round().clamp(0, w - 1).nan_to_num(0).long()
            iy = py.round().clamp(0, h - 1).nan_to_num(0).long()
            out |= near[None] & big[0][iy, ix][None]
    return out


def _kfield(*args):
    """K.vector_field as int64 (the kernel's field is uint32: the same entries, half the
    bytes; the reference's is int64)."""
    f = K.vector_field(*args)
    assert f.dtype == torch.uint32
    return f.to(torch.int64)


@pytest.mark.parametrize("h,w", [(37, 53), (72, 128), (5, 9), (1, 1), (16, 9)])
def test_fsr3_block_vector_field(h, w):
    """The optical flow's field from vectors and priorities per 8 x 8 block (block=8: the
    entries kernel reads each pixel's block, frames not a multiple of 8 included): the
    reference's field of the upsampled vectors and priorities, exactly; other block sizes
    and the secondary walk (upsampled first) too."""
    from fgcli.ops import fsr3

    c0, c1, _, _ = _fsr3_inputs(h, w, h * 5 + w)
    g = torch.Generator().manual_seed(h * 3 + w)
    for b in (8, 4, 3):
        nby, nbx = -(-h // b), -(-w // b)
        f = torch.randn(2, nby, nbx, generator=g) * 6.0
        f.view(-1)[::7] = torch.round(f.view(-1)[::7])
        f.view(-1)[::11] = 0.0
        if f.numel() > 4:
            f[0].view(-1)[1] = NAN
            f[1].view(-1)[2] = INF
            f[0].view(-1)[3] = -1e9
        if nby >= 5:  # rows of zero vectors (+0 and -0; one with a subnormal)
            f[:, 2] = 0.0
            f[:, 3] = -0.0
            f[0, 4] = 0.0
            f[1, 4] = -0.0
            f[1, 4, -1] = 1e-45
        if nbx >= 4:  # blocks sharing a vector: runs of 16 and more sources
            f[:, nby // 2:, :nbx // 2 + 2] = torch.tensor([2.3, -1.7])[:, None, None]
        hi = fsr3.magnitude_priority(f)
        up = (fsr3.upsample_block_flow(f, h, w, b), fsr3.upsample_block_flow(hi, h, w, b))
        for a in (0.5, 0.25):
            for sec in (False, True):
                ref = fsr3.vector_field(c0, c1, *up, a, sec)
                same(f"block field {b} {a} {sec}", _kfield(c0, c1, f, hi, a, sec, 64, 0.05,
                                                           None, b), ref)
                same(f"block field (reference) {b} {a} {sec}",
                     fsr3.vector_field(c0, c1, f, hi, a, sec, block=b), ref)
        for thr in (0.0, -0.5, 1.0, 0.999):  # (the tap rule at its ends)
            same(f"block field {b} thr={thr}", _kfield(c0, c1, f, hi, 0.5, False, 64, thr,
                                                       None, b),
                 fsr3.vector_field(c0, c1, *up, 0.5, False, tap_threshold=thr))


@pytest.mark.parametrize("h,w", [(37, 53), (72, 128), (5, 9), (1, 1)])
def test_fsr3_game_vector_field(h, w):
    """The game field with its depth priorities made inside the priority kernel: the
    reference's depth_priority then vector_field, exactly (sky, NaN, zero and negative
    depths, huge, NaN and inf vectors; with and without the walk, given luma0 or not); a
    depth of another size is refused, naming it, on both backends."""
    from fgcli.ops import fsr3

    c0, c1, v, d = _fsr3_inputs(h, w, h * 11 + w)
    d.view(-1)[5::9] = -2.0
    d.view(-1)[7::13] = 1e-30
    d.view(-1)[8::17] = 3e38
    l0 = K.field_luminance(c0)
    for a in (0.5, 0.25):
        for sec in (False, True):
            ref = fsr3.vector_field(c0, c1, v, fsr3.depth_priority(d), a, sec)
            same(f"reference {a} {sec}", fsr3.game_vector_field(c0, c1, v, d, a, sec), ref)
            for lum in (None, l0):
                f = K.game_vector_field(c0, c1, v, d, a, sec, luma0=lum)
                assert f.dtype == torch.uint32
                same(f"kernels {a} {sec} {lum is None}", f.to(torch.int64), ref)
    for fn in (K.game_vector_field, fsr3.game_vector_field):
        with pytest.raises(ValueError, match="depth"):
            fn(c0, c1, v, torch.ones(1, h + 1, w), 0.5)


@pytest.mark.parametrize("h,w", [(37, 53), (5, 9), (1, 1)])
def test_fsr3_field_luminance_shared(h, w):
    """Frame 0's luminance plane computed once for both fields (vector_field's luma0):
    the kernel's plane is the reference's (HDR, NaN and inf colour, and a colour whose
    luminance overflows), and a field given it equals the field computing its own, per
    pixel and per block, on both backends; a plane of the wrong size is refused."""
    from fgcli.ops import fsr3

    c0, c1, v, d = _fsr3_inputs(h, w, h * 7 + w)
    c0[:, -1, -1] = 3e38  # (the luminance overflows to inf, then is sanitised)
    l0 = K.field_luminance(c0)
    same("field_luminance", l0, fsr3.field_luminance(c0))
    hi = fsr3.depth_priority(d)
    for a in (0.5, 0.25):
        for sec in (False, True):
            ref = fsr3.vector_field(c0, c1, v, hi, a, sec)
            same(f"reference with luma0 {a} {sec}",
                 fsr3.vector_field(c0, c1, v, hi, a, sec, luma0=l0), ref)
            same(f"kernels with luma0 {a} {sec}",
                 _kfield(c0, c1, v, hi, a, sec, 64, 0.05, None, 1, l0), ref)
    nby, nbx = -(-h // 8), -(-w // 8)
    f = torch.randn(2, nby, nbx, generator=torch.Generator().manual_seed(1)) * 5.0
    fh = fsr3.magnitude_priority(f)
    same("block field with luma0", _kfield(c0, c1, f, fh, 0.5, False, 64, 0.05, None, 8, l0),
         fsr3.vector_field(c0, c1, f, fh, 0.5, False, block=8))
    for fn in (K.vector_field, fsr3.vector_field):
        with pytest.raises(ValueError, match="luma0"):
            fn(c0, c1, v, hi, 0.5, False, luma0=torch.zeros(1, h + 1, w))


def test_fsr3_field_bands_and_deferred_sources():
    """The two-component field scatters work in bands of source rows, every other band in
    parallel, and defer a source whose footprint leaves its band's zone (half a band each
    way) to a last pass: fields with runs of 16 equal vectors inside and across zones (and
    of exactly 15), vertical motion of a few rows (kept) and of many (deferred), per pixel and per 8 x 8
    block, equal the reference exactly."""
    from fgcli.kernels.field import _bands
    from fgcli.ops import fsr3

    h, w = 160, 72
    bh, nband = _bands.py_func(h)
    assert nband >= 8 and bh >= 8
    c0, c1, _, d = _fsr3_inputs(h, w, 3)
    v = torch.zeros(2, h, w)
    v[0] = 2.3  # runs: each row's sources continue each other's footprints
    v[1, : h // 4] = 3.7  # a few rows down: inside the zone
    v[1, h // 4: h // 2] = -(bh + 2.5) * 2  # more than half a band at alpha 0.5: deferred
    v[1, h // 2:, ::5] = (bh * 3.0) * 2
    v[:, 3 * h // 4:, 20:40] = torch.tensor([-1.4, 0.6])[:, None, None]
    v[1, bh - 1:bh + 1] = bh / 2.0 * 2  # rows at a band's edge, their footprint at the zone's
    v[0, 4:8, 15::16] = 7.9  # runs of exactly 15 sources (the 16th breaks each)
    v[0, 4:8, 46::16] = 7.9  # (and runs starting elsewhere)
    # the kept and the deferred sources both occur
    a1 = 0.5
    y = torch.arange(h, dtype=torch.float32)[:, None]
    ty = torch.floor((y + v[1] * a1).clamp(-2.0, h + 1.0)).clamp(-1.0, h) + 1
    ya = (torch.arange(h)[:, None] // bh) * bh
    inside = (ty >= ya - bh // 2 + 1) & (ty + 1 < torch.clamp(ya + bh, max=h) + bh // 2 + 1)
    assert inside.any() and not inside.all()
    hi = fsr3.depth_priority(d)
    for sec in (False, True):
        same(f"pixel field {sec}", _kfield(c0, c1, v, hi, 0.5, sec),
             fsr3.vector_field(c0, c1, v, hi, 0.5, sec))
    f = v[:, ::8, ::8].contiguous()
    fh = fsr3.magnitude_priority(f)
    up = (fsr3.upsample_block_flow(f, h, w, 8), fsr3.upsample_block_flow(fh, h, w, 8))
    same("block field", _kfield(c0, c1, f, fh, 0.5, False, 64, 0.05, None, 8),
         fsr3.vector_field(c0, c1, *up, 0.5, False))


@pytest.mark.parametrize("h,w", [(37, 53), (72, 128), (5, 9), (1, 1)])
def test_fsr3_scatters(h, w):
    """FSR 3's footprint scatters (vector field with and without the secondary walk,
    depth reconstruction): a max / min over the reference's own float positions, so equal
    to the reference exactly."""
    from fgcli.ops import fsr3

    c0, c1, v, d = _fsr3_inputs(h, w, h * 7 + w)
    hi = fsr3.depth_priority(d)
    for a in (0.5, 0.3, 0.0, 1.0):
        for sec, ms in ((True, 64), (True, 2), (False, 64)):
            same("field", _kfield(c0, c1, v, hi, a, sec, ms),
                 fsr3.vector_field(c0, c1, v, hi, a, sec, ms))
        for k, r in zip(K.reconstruct_depths(d, v, a), fsr3.reconstruct_depths(d, v, a)):
            same("depth", k, r)
    assert torch.equal(_kfield(c0, c1, v * 0, hi), fsr3.vector_field(c0, c1, v * 0, hi))
    # depth reconstruction zeroes vectors shorter than 0.1 px: lengths within a few ulps of
    # it, along the axes and the diagonal (the kernel works the length out itself)
    if h >= 8:
        tenth = torch.tensor(0.1)
        steps = torch.arange(w) - w // 2
        ax = tenth + steps * 2e-9  # float32 neighbours of 0.1 and a little beyond
        vs = v.clone()
        vs[0, 5], vs[1, 5] = ax, 0.0
        vs[0, 6], vs[1, 6] = 0.0, -ax
        vs[0, 7] = vs[1, 7] = ax / math.sqrt(2.0)
        assert {bool(b) for b in fsr3._length(vs[:, 5:8].reshape(2, -1)) >= 0.1} == {True, False}
        for a in (0.5, 0.3):
            for k, r in zip(K.reconstruct_depths(d, vs * 10, a, short_mv=1.0),
                            fsr3.reconstruct_depths(d, vs * 10, a, short_mv=1.0)):
                same("depth (short vectors)", k, r)
            for k, r in zip(K.reconstruct_depths(d, vs, a), fsr3.reconstruct_depths(d, vs, a)):
                same("depth (short vectors)", k, r)


def test_sqrt_threshold(monkeypatch):
    """The depth reconstruction's short-vector test without square roots: x >= T gives
    torch.sqrt(x) >= short for every float32 x within 3000 values of T (both ways; beyond
    that the square root's error of an ulp or two cannot reach), for shorts from 1e-30
    (square underflowing: no threshold, or one that holds) up; 0 and negatives let every
    vector pass, NaN and inf none; without a threshold the kernel takes the square roots
    and gives the reference's depths too."""
    from fgcli.ops import fsr3

    for s in (0.1, 1.0, 0.3, 1e-3, 7.5, 9.99, 1e-19, 1e-30):
        t = K._sqrt_at_least(s)
        if t is None:
            assert s < 1e-18
            continue
        c = int(np.float32(t).view(np.int32))
        x = torch.from_numpy(np.arange(max(c - 3000, 0), c + 3000, dtype=np.int32)
                             .view(np.float32))
        assert torch.equal(torch.sqrt(x) >= s, x >= float(t)), s
        assert bool(torch.sqrt(torch.tensor(float(t))) >= s)
    assert K._sqrt_at_least(0.1) is not None
    assert K._sqrt_at_least(0.0) == 0.0 and K._sqrt_at_least(-1.0) == 0.0
    assert K._sqrt_at_least(float("nan")) == np.inf and K._sqrt_at_least(np.inf) == np.inf
    c0, c1, v, d = _fsr3_inputs(37, 53, 5)
    v[:, ::3] *= 0.02  # (many vectors near 0.1 px)
    want = fsr3.reconstruct_depths(d, v, 0.5)
    for kr, r in zip(K.reconstruct_depths(d, v, 0.5), want):
        same("depth (threshold)", kr, r)
    monkeypatch.setattr(K, "_sqrt_at_least", lambda s: None)
    for kr, r in zip(K.reconstruct_depths(d, v, 0.5), want):
        same("depth (square roots)", kr, r)


def test_pair16_equals_two_overlapping_updates():
    """fmin16x2 / umax16x2 (the footprint scatters' two taps of a run merged in registers)
    write what fmin16 / umax16 twice write, the second one texel to the right (d = 1) or
    on the same texels (d = 0), bit for bit: signed zeros and +inf included (the minimum
    keeps the older value on ties, as the sequential updates do)."""
    from numba import njit

    from fgcli.kernels._intrin import fmin16, fmin16x2, umax16, umax16x2

    @njit(cache=False)
    def seq(buf, q, a, b, j, d, ubuf, ua, ub):
        fmin16(buf, q, a, j)
        fmin16(buf, q + d, b, j)
        umax16(ubuf, q, ua, j)
        umax16(ubuf, q + d, ub, j)

    @njit(cache=False)
    def pair(buf, q, a, b, j, d, ubuf, ua, ub):
        fmin16x2(buf, q, a, b, j, d)
        umax16x2(ubuf, q, ua, ub, j, d)

    rng = np.random.default_rng(3)
    vals = np.array([0.0, -0.0, 0.25, 1.0, 3.0, np.inf], dtype=np.float32)
    for _ in range(300):
        d, q, j = int(rng.integers(0, 2)), int(rng.integers(0, 20)), int(rng.integers(0, 8))
        buf, a, b = rng.choice(vals, 40), rng.choice(vals, 24), rng.choice(vals, 24)
        ubuf, ua, ub = (rng.integers(0, 2 ** 32, n, dtype=np.uint64).astype(np.uint32)
                        for n in (40, 24, 24))
        r1 = [buf.copy(), ubuf.copy()]
        r2 = [buf.copy(), ubuf.copy()]
        seq(r1[0], q, a, b, j, d, r1[1], ua, ub)
        pair(r2[0], q, a, b, j, d, r2[1], ua, ub)
        assert r1[0].view(np.uint32).tolist() == r2[0].view(np.uint32).tolist(), (q, j, d)
        assert r1[1].tolist() == r2[1].tolist(), (q, j, d)


def test_fsr3_field_scatter_runs():
    """The field scatter writes runs of 16 sources whose footprints continue each other
    (smooth motion) as vector maxima: regions of one sub-pixel vector each (all four taps
    written), runs cut by a region's edge, by a clamped tap at the frame's edge and by
    chunk ends, beside random vectors; against the reference exactly. The depth
    reconstruction on the same vectors, with zeros, negatives, NaN, +-inf and runs of
    equal depths."""
    from fgcli.ops import fsr3

    g = torch.Generator().manual_seed(11)
    for h, w in ((40, 2100), (19, 67)):  # (2100: a row spans a chunk end of 2048 sources)
        c0, c1 = torch.rand(3, h, w, generator=g), torch.rand(3, h, w, generator=g)
        v = torch.randn(2, h, w, generator=g) * 3.0
        v[0, : h // 2, : w // 2] = 0.3  # one sub-pixel vector per region
        v[1, : h // 2, : w // 2] = -0.6
        v[0, h // 2:, w // 3:] = -7.45
        v[1, h // 2:, w // 3:] = 2.2
        v[:, 3, :] = torch.tensor([[40.5], [0.5]])  # runs off the right edge
        for r, n in ((5, 31), (7, 47), (9, 16), (11, 17)):  # a run, then one that breaks it
            v[:, r, :n] = torch.tensor([[2.3], [0.45]])
        d = torch.rand(1, h, w, generator=g) + 0.5
        hi = fsr3.depth_priority(d)
        d[0, 5, 3:9] = torch.tensor([0.0, -1.0, float("nan"), float("inf"), -float("inf"), -0.0])
        d[0, 9:12, :40] = 2.0  # equal depths over runs
        d[0, 2::7, ::5] = 0.0
        for a in (0.5, 0.25):
            for sec in (False, True):
                same("field runs", _kfield(c0, c1, v, hi, a, sec, 64),
                     fsr3.vector_field(c0, c1, v, hi, a, sec, 64))
            for k, r in zip(K.reconstruct_depths(d, v, a), fsr3.reconstruct_depths(d, v, a)):
                same("depth runs", k, r)


@pytest.mark.parametrize("h,w", [(37, 53), (72, 128), (12, 16)])
def test_fsr3_static_rows(h, w):
    """Rows of zero vectors (the static parts of a frame) take the kernels' own-texel paths
    (each pixel's taps on itself: the disocclusion masks, the depth reconstruction's two
    scatters, the game field's scatter): +0 and -0 rows, a NaN (sanitised to 0; a moving
    row for the masks) or a subnormal in an otherwise zero row, rows of short vectors
    (zeroed by the depth reconstruction), with NaN, inf, 0 and -0 depths, beside moving
    rows whose footprints land in them; tap thresholds outside [0, 1) take the general
    path. Against the reference, exactly."""
    from fgcli.ops import fsr3

    c0, c1, _, d = _fsr3_inputs(h, w, 7 * h + w)
    g = torch.Generator().manual_seed(h * w)
    v = torch.randn(2, h, w, generator=g) * 2.0  # (moving rows reach the rows beside them)
    v[:, 0::3] = 0.0
    v[1, 0::6] = -0.0
    v[0, 3::9, w // 2] = NAN
    v[1, 6::9, 0] = 1e-45
    v[:, 1::9] = 0.04  # shorter than short_mv
    d = d.clone()
    d[0, ::3, ::5] = NAN
    d[0, ::3, 1::7] = INF
    d[0, 3::6, 2::9] = 0.0
    d[0, ::6, 3::11] = -0.0
    assert int((v == 0).all(0).all(1).sum()) >= 2  # (rows the own-texel paths take)
    dp = d.flip(-1).clone()
    dp[0, ::4, ::3] = 0.0
    for a in (0.5, 0.3, 0.0, 1.0):
        same_result(f"masks a={a}", K.disocclusion_masks(d, dp, d.flip(-2), v, a, 1.4),
                    fsr3.disocclusion_masks(d, dp, d.flip(-2), v, a, 1.4))
        for tt in (0.05, 0.0, 1.0, -0.5):
            for kr, r in zip(K.reconstruct_depths(d, v, a, tap_threshold=tt),
                             fsr3.reconstruct_depths(d, v, a, tap_threshold=tt)):
                same(f"depths a={a} thr={tt}", kr, r)
            for sec in (False, True):
                same(f"game field a={a} thr={tt} sec={sec}",
                     K.game_vector_field(c0, c1, v, d, a, sec, tap_threshold=tt).to(
                         torch.int64),
                     fsr3.game_vector_field(c0, c1, v, d, a, sec, tap_threshold=tt))


def test_fsr3_walk_over_threads():
    """The secondary walk with both threads writing the fields (atomic maxima, nothing
    written at primary texels): a frame of 128 rows (every chunk of the parallel loop
    holds rows) where a layer moving 30 px over a static one leaves a wide disocclusion
    that the walks of many sources, from chunks on both threads, write into and compete
    for (random priorities), and long walks that stop at their fourth primary texel: the
    reference's field, exactly, on every run (the maxima do not depend on the threads'
    order)."""
    from fgcli.ops import fsr3

    g = torch.Generator().manual_seed(17)
    h, w = 128, 96
    c0, c1 = torch.rand(3, h, w, generator=g), torch.rand(3, h, w, generator=g)
    v = torch.zeros(2, h, w)
    v[0, :, : w // 2] = 30.0 + torch.rand(h, w // 2, generator=g) * 4.0
    v[1, :, : w // 2] = torch.randn(h, w // 2, generator=g) * 6.0
    v[:, 40:60] *= -1.0  # walks crossing each other
    hi = (fsr3.magnitude_priority(v) + torch.randint(0, 7, (h, w), generator=g)).clamp(max=1023)
    d = torch.rand(1, h, w, generator=g) + 0.5
    for a in (0.5, 0.25):
        ref = fsr3.vector_field(c0, c1, v, hi, a, True, 64)
        sec = ref[0] < (1 << 31)
        assert (sec & (ref[0] > 0)).sum() > 500  # (secondary entries the walk wrote)
        for _ in range(3):
            same("walk over threads", _kfield(c0, c1, v, hi, a, True, 64), ref)
        gref = fsr3.vector_field(c0, c1, v, fsr3.depth_priority(d), a, True)
        for _ in range(3):
            same("game walk over threads",
                 K.game_vector_field(c0, c1, v, d, a, True).to(torch.int64), gref)


def test_fsr3_lengths_take_torchs_sqrt():
    """The short-vector test of depth reconstruction and the secondary walk's lengths use
    torch.sqrt over the whole plane, as the reference (MKL's on x86 builds, which differs
    from IEEE sqrt by one ulp on some inputs, and by position in the array): thresholds
    set at the reference's own length of vectors where its sqrt and IEEE's differ (where
    torch's is the larger, a kernel with its own sqrt calls the vector short), and the
    secondary walk over such lengths, both against the reference."""
    import numpy as np

    from fgcli.ops import fsr3

    g = torch.Generator().manual_seed(3)
    h, w = 48, 64
    v = torch.zeros(2, h, w)
    v[0] = torch.rand(h, w, generator=g) * 40 + 1
    v[1] = torch.rand(h, w, generator=g) * 3
    ref_len = fsr3._length(v.reshape(2, -1))  # the reference's lengths, in place
    ss = (v.reshape(2, -1) ** 2).sum(0)
    ieee = torch.from_numpy(np.sqrt(ss.numpy()))
    picks = (ref_len > ieee).nonzero().view(-1)[:4].tolist() or [0]
    d = torch.rand(1, h, w, generator=g) + 1.0
    for i in picks:
        short = float(ref_len[i])
        for a, b in zip(K.reconstruct_depths(d, v, 0.5, short_mv=short),
                        fsr3.reconstruct_depths(d, v, 0.5, short_mv=short)):
            same("depth (torch's sqrt)", a, b)
    c0, c1, _, _ = _fsr3_inputs(h, w, 5)
    hi = fsr3.depth_priority(d)
    for a in (0.0, 0.5):
        same("field (torch's sqrt)", _kfield(c0, c1, v, hi, a, True, 64),
             fsr3.vector_field(c0, c1, v, hi, a, True, 64))
    # the walk's threshold (the roots are taken of the walking pixels only): (1 - alpha)
    # |v| at 1 and a few ulps either side, rows of short vectors only, none walking at all
    v2 = v.clone()
    one = torch.tensor([1.0]).view(torch.int32)
    edge = (one + torch.arange(-3, 4, dtype=torch.int32)).view(torch.float32) * 2.0
    v2[0, :, : edge.numel()] = edge
    v2[1, :, : edge.numel()] = 0.0
    v2[:, h // 2:] *= 0.01
    for vv in (v2, v * 0.01):
        same("field (walk threshold)", _kfield(c0, c1, vv, hi, 0.5, True, 64),
             fsr3.vector_field(c0, c1, vv, hi, 0.5, True, 64))


@pytest.mark.parametrize("h,w", [(37, 53), (5, 9), (1, 1)])
def test_fsr3_output_vectors(h, w):
    """The interpolated frame's vectors, sanitize_mv(vec) * scale in one pass: NaN, +-inf
    and huge components, scales 0, negative, non-representable in float32, and a
    non-contiguous input (the reference's path)."""
    from fgcli.ops import fsr3

    _, _, v, _ = _fsr3_inputs(h, w, 3 * h + w)
    v[0, 0, 0] = -INF
    v[1, -1, -1] = -1e9
    for s in (0.5, 0.0, -0.25, 1.0 / 3.0, 0.7000000001):
        same(f"output_vectors {s}", K.output_vectors(v, s), fsr3.output_vectors(v, s))
    t = v.transpose(1, 2)
    same("non-contiguous", K.output_vectors(t, 0.3), fsr3.output_vectors(t, 0.3))
    with pytest.raises(ValueError):
        K.output_vectors(v[:1], 0.5)


def test_torch_math_position_free():
    """What the kernels' callers rely on when they take torch.log / torch.sqrt of a part of
    what the reference takes them of (the match search's taps, the sky rows): the result
    for an element does not depend on its position, its neighbours or the tensor's
    length (vector body or tail; MKL's sqrt and Sleef's log differ from IEEE's / libm's
    on some inputs, which is why the kernels call torch at all). Values where both
    differ from numpy's, in every length up to two vector widths and a few large ones,
    at every offset of a 64-element block, and gathered."""
    import numpy as np

    rng = np.random.default_rng(7)
    n = 1 << 16
    x = (rng.standard_normal(n).astype(np.float32) ** 2
         * rng.choice(np.array([1e-30, 1e-3, 1.0, 1e3, 1e30], dtype=np.float32), n))
    x = torch.from_numpy(x + np.float32(1e-30))
    for f in (torch.log, torch.sqrt):
        full = f(x)  # (x86 builds: 6 % of these logs and 14 % of the roots differ from
        # numpy's; elsewhere torch's may be IEEE's, and the test holds trivially)
        for m in list(range(1, 70)) + [255, 1000, 4097, 40000]:
            for off in range(0, 64, 1 if m < 70 else 13):
                part = f(x[off:off + m].clone())
                assert torch.equal(part.view(torch.int32),
                                   full[off:off + m].view(torch.int32)), (f, m, off)
        idx = torch.from_numpy(rng.integers(0, n, 777))
        assert torch.equal(f(x[idx]).view(torch.int32), full[idx].view(torch.int32))


@pytest.mark.parametrize("h,w", [(37, 53), (72, 128), (5, 9), (1, 1)])
def test_fsr3_masks_and_interpolation(h, w):
    """FSR 3's disocclusion masks and interpolation pass: one kernel pass each, the
    reference's float32 operations one by one (hard cases: sky, NaN and zero depths; NaN,
    inf and huge vectors; HDR, NaN and inf colour; masks off-screen; alpha at both ends;
    rows and blocks of zero optical flow, which take the pixels without fetching)."""
    from fgcli.ops import fsr3

    c0, c1, v, d = _fsr3_inputs(h, w, h * 5 + w)
    g = torch.Generator().manual_seed(h + w)
    dp = d.flip(-1).clone()
    dp[0, ::3, ::2] = 0.0
    of = torch.randn(2, h, w, generator=g) * 3.0
    of[0, :1] = NAN
    c0 = c0.clone()
    c0[0, :1] = 1e30
    c0[1, -1:] = INF
    c1 = c1.clone()
    c1[2, :, :1] = NAN
    c1[:, :1, -1:] = 0.0
    # static parts: rows of zero flow (+0 and -0), blocks of 16 in moving rows, a NaN and a
    # subnormal (scaled to 0) in otherwise zero rows
    of_static = of.clone()
    of_static[:, 1::3] = 0.0
    of_static[1, 1::6] = -0.0
    of_static[:, 2::3, :min(w, 40)] = 0.0
    of_static[0, 4::6, -1] = 1e-45
    of_static[1, 7::9, 0] = NAN
    for a in (0.5, 0.3, 0.0, 1.0):
        mk = K.disocclusion_masks(d, dp, d.flip(-2), v, a, 1.4)
        same_result("masks", mk, fsr3.disocclusion_masks(d, dp, d.flip(-2), v, a, 1.4))
        for o in (None, of, v * 0, of_static):
            same_result(f"interp a={a}", K.interpolate_fsr3(c0, c1, v, mk[0], mk[1], a, o),
                        fsr3.interpolate_fsr3(c0, c1, v, mk[0], mk[1], a, o),
                        C["interpolate_fsr3"], _tap_on_huge_value(c0, c1, v, o, a))
        d0 = d.flip(-1).clone()
        d0[0, :1] = NAN
        d0[0, 1:2, :3] = -1.0
        dt = d.clone()
        dt[0, ::2] = INF  # rows all +inf (sky), rows with a few (one by one) and with
        dt[0, 1::4, ::7] = INF  # many (the row's lookups), mixed with depths
        dt[0, 3::4, ::3] = INF
        dt[0, -1, :2] = NAN
        v2 = v.clone()
        v2[0, -1:] = NAN
        for dd in ((d0, d), (None, None)):
            k = K.interpolated_depth(dt, v2, a, *dd)
            r = fsr3.interpolated_depth(dt, v2, a, *dd)
            assert torch.equal(k.view(torch.int32), r.view(torch.int32)), "depth"
        # (a depth of another size: the reference's error, not a kernel reading past it)
        for f in (K.interpolated_depth, fsr3.interpolated_depth) if w > 1 else ():
            with pytest.raises(ValueError, match="size"):
                f(dt, v2, a, d0, d[..., :1])
    # display space runs the reference
    one = torch.ones(1, h, w)
    same_result("display", K.interpolate_fsr3(c0, c1, v, one, one, 0.5, of, "display"),
                fsr3.interpolate_fsr3(c0, c1, v, one, one, 0.5, of, "display"))


@pytest.mark.parametrize("path", ["int", "f16c"])
def test_half_bits(path):
    """The float32 -> binary16 conversion of the packed field entries, against torch's,
    by both paths: integer arithmetic, and the CPU's conversion where it has F16C (every
    finite float32 within +-65504 was checked once, 2.4e9 values, 38 s, for the first; for
    the second, every 7th bit pattern, 3.4e8 values; here: the boundaries of every
    exponent, subnormals, ties and random values)."""
    import numpy as np
    from numba import njit

    from fgcli.kernels import field
    from fgcli.kernels._intrin import HAVE_F16C

    if path == "f16c" and not HAVE_F16C:
        pytest.skip("no F16C on this CPU")
    fn = field.half_bits_int if path == "int" else field._half_bits_f16c
    assert field.half_bits is (field._half_bits_f16c if HAVE_F16C else field.half_bits_int)

    @njit
    def conv(src, out):
        for i in range(src.shape[0]):
            out[i] = fn(src[i])

    g = torch.Generator().manual_seed(0)
    e = torch.arange(-40, 17, dtype=torch.float32)
    base = torch.cat([2.0 ** e, (2.0 ** e) * 1.5, (2.0 ** e) * (1 + 2.0 ** -11),
                      (2.0 ** e) * (1 + 3 * 2.0 ** -11), torch.tensor([0.0, 65504.0, 65519.0,
                      6.0e-8, 2.9e-8, 3.0e-8, 1e-45])])
    x = torch.cat([base, torch.randn(200000, generator=g) * 100,
                   torch.randn(20000, generator=g) * 1e-5])
    x = x.clamp(-65504.0, 65504.0)
    x = torch.cat([x, -x])
    x = torch.cat([x, torch.nextafter(x, torch.full_like(x, INF)),
                   torch.nextafter(x, torch.full_like(x, -INF))]).clamp(-65504.0, 65504.0)
    out = np.empty(x.numel(), dtype=np.int64)
    conv(x.numpy(), out)
    ref = x.to(torch.float16).view(torch.int16).to(torch.int64) & 0xFFFF
    assert torch.equal(torch.from_numpy(out), ref)


def test_fill_packed_field_reads_every_half():
    """Every binary16 pattern (NaN, inf, subnormals, -0.0) in both components, written and
    unwritten texels, against the reference: the field as given, the scatter's padded
    buffer read in place (its ring holds other values: a read of it would show), and both
    as uint32 (the kernel's vector_field)."""
    from fgcli.ops import fsr3

    b = torch.arange(65536, dtype=torch.int64)
    prio = torch.randint(0, 65536, (65536,), generator=torch.Generator().manual_seed(1))
    prio[::7] = 0  # unwritten
    f = torch.stack([(prio << 16) | b, (prio << 16) | b.flip(0)]).view(2, 256, 256)
    r = fsr3.fill_packed_field(f)
    padded = torch.full((2, 258, 258), (7 << 16) | 0x3C00, dtype=torch.int64)
    padded[:, 1:257, 1:257] = f
    view = padded[:, 1:257, 1:257]
    assert K._padded_base(view)[1] == 1 and K._padded_base(f)[1] == 0
    u32 = padded.to(torch.uint32)[:, 1:257, 1:257]
    assert K._padded_base(u32)[1] == 1
    for name, x in (("given", f), ("in place", view), ("uint32", f.to(torch.uint32)),
                    ("uint32 in place", u32)):
        k = K.fill_packed_field(x)
        same_result(f"packed fill, {name}", k, r, C["fill_packed_field"])
        zero_signs_alike(name, k[0], r[0])
        same_result(f"packed fill, {name} (reference)", fsr3.fill_packed_field(x), r)


@pytest.mark.parametrize("h,w", [(72, 128), (37, 53), (1, 9), (9, 1), (2, 2)])
def test_fill_packed_field(h, w):
    """The unpacking, weight and inpainting's dense part in one kernel: the reference's
    vectors and mask exactly, for int64 and uint32 fields, the scatter's padded view,
    every binary16 class (NaN, inf, subnormal, -0.0), wide and scattered holes, none, and
    no texel written at all."""
    from fgcli.ops import fsr3

    g = torch.Generator().manual_seed(h * 31 + w)
    n = h * w
    bits = torch.randint(0, 65536, (2, n), generator=g)
    bits[:, :8] = torch.tensor([0x7E00, 0x7C00, 0xFC00, 0x0001, 0x8000, 0x3C00, 0x83FF,
                                0x7BFF])[: min(8, n)]
    prio = torch.randint(1, 65536, (n,), generator=g)
    cases = {"scattered": torch.rand(n, generator=g) < 0.3,
             "no holes": torch.zeros(n, dtype=torch.bool),
             "all holes": torch.ones(n, dtype=torch.bool)}
    wide = torch.zeros(h, w, dtype=torch.bool)
    wide[: max(1, h // 2), : max(1, w // 3)] = True
    cases["wide"] = wide.view(-1)
    for name, hole in cases.items():
        p = torch.where(hole, 0, prio)
        f = ((p << 16)[None] | bits).view(2, h, w)
        r = fsr3.fill_packed_field(f)
        padded = torch.zeros(2, h + 2, w + 2, dtype=torch.uint32)
        padded[:, 1:h + 1, 1:w + 1] = f.to(torch.uint32)
        for x in (f, f.to(torch.uint32), padded[:, 1:h + 1, 1:w + 1]):
            k = K.fill_packed_field(x)
            same_result(f"packed fill ({name})", k, r, C["fill_packed_field"])
            zero_signs_alike(name, k[0], r[0])
        assert bool(r[1].all()) == (name == "no holes")
        assert bool(r[1].any()) == (name != "all holes")


@pytest.mark.parametrize("h,w,block", [(1080, 1920, 8), (37, 53, 8), (9, 17, 8), (1, 1, 8),
                                       (5, 3, 1), (64, 40, 4)])
def test_sample_flow_field(h, w, block):
    """fsr3-interp:field=block's per-pixel sampling of the block field against the
    reference: written and unwritten texels, every binary16 pattern class (NaN, inf,
    subnormal, -0.0), texels off the grid at the edges, grids of one texel."""
    from fgcli.ops import fsr3

    fh, fw = -(-h // block), -(-w // block)
    g = torch.Generator().manual_seed(h + 7 * w + block)
    bits = torch.randint(0, 65536, (2, fh, fw), generator=g)
    special = torch.tensor([0x7E00, 0x7C00, 0x0001, 0x8000])
    n = min(4, bits.numel())
    bits.view(-1)[:n] = special[:n]
    prio = torch.randint(0, 65536, (1, fh, fw), generator=g)
    prio.view(-1)[::3] = 0  # unwritten
    field = (prio << 16) | bits
    k = K.sample_flow_field(field, h, w, block)
    r = fsr3.sample_flow_field(field, h, w, block)
    same("sample_flow_field", k, r)
    assert bool(torch.isfinite(k).all())
    # a valid, smooth field: the interior is the bilinear mean of the texels
    v = torch.randn(2, fh, fw, generator=g) * 4
    one = fsr3.pack_entries(True, torch.full((fh * fw,), 5), torch.zeros(fh * fw, dtype=torch.int64),
                            v.reshape(2, -1)[0]).view(1, fh, fw)
    two = fsr3.pack_entries(True, torch.full((fh * fw,), 5), torch.zeros(fh * fw, dtype=torch.int64),
                            v.reshape(2, -1)[1]).view(1, fh, fw)
    field = torch.cat([one, two])
    same("sample_flow_field valid", K.sample_flow_field(field, h, w, block),
         fsr3.sample_flow_field(field, h, w, block))


@pytest.mark.parametrize("h,w", [(1080, 1920), (37, 53), (1, 5), (5, 1), (1, 1), (3, 3)])
def test_pyramid_level_and_fills(h, w):
    """The mip level kernel against avg_pool2d(ceil_mode) bit for bit (odd edges, zeros,
    -0.0, HDR), and FSR 3's two pyramid fills through it."""
    from fgcli.ops import fsr3, pyramid

    g = torch.Generator().manual_seed(h * 3 + w)
    x = torch.randn(4, h, w, generator=g) * torch.rand(4, h, w, generator=g) * 1000
    x[0, ::7] = 0.0
    x[1, ::3] = -0.0
    x[2, :, ::5] = 3e37
    assert torch.equal(K.avg_pool2(x).view(torch.int32), pyramid.avg_pool2(x).view(torch.int32))
    if h * w > 10000:
        return
    c0, c1, v, d = _fsr3_inputs(h, w, h + w)
    holes = torch.rand(1, h, w, generator=g) < 0.3
    holes[:, : max(1, h // 3), : max(1, w // 3)] = True  # a wide hole: coarse levels
    same_result("inpaint", K.inpaint_color(c0, holes), fsr3.inpaint_color(c0, holes),
                C["inpaint_color"])


def test_depth_priority_is_the_reference():
    """FSR 3's 10-bit depth priority: the kernel gives the reference's ranks exactly:
    depths over 42 decades with both float32 neighbours of each
    (so that ranks change between neighbours somewhere), sky, NaN, negative, -0.0 and the
    1e30 clamp."""
    from fgcli.ops import fsr3

    d = torch.logspace(-30, 12, 300_000, dtype=torch.float64).to(torch.float32)
    d = torch.cat([d, torch.nextafter(d, torch.full_like(d, INF)),
                   torch.nextafter(d, torch.zeros_like(d)),
                   torch.tensor([NAN, INF, -INF, -1.0, -0.0, 0.0, 1e-45, 1e30, 2e30, 3e38])])
    d = d[: d.numel() // 7 * 7].view(1, 7, -1)
    k, r = K.depth_priority(d), fsr3.depth_priority(d)
    assert k.dtype == r.dtype == torch.int64 and torch.equal(k, r)
    assert len(set(r.view(-1).tolist())) == 1023  # every rank, so every boundary, is met


def test_depth_priority_ranks_exactly():
    """depth_priority's table is floor(1023 / (1 + min(d, 1e30)^0.33)) clamped to 1..1023
    in exact arithmetic (float64 here): every threshold and its 4 float32 neighbours each
    side, 200k depths over 78 decades, 0, the smallest denormal, 1e30 and beyond, +inf
    (all 2.1e9 non-negative float32 were checked the same way once: no difference)."""
    import numpy as np

    from fgcli.ops import fsr3

    base, thr, b0 = fsr3.depth_priority_table()
    t = thr[~np.isnan(thr)].view(np.int32).astype(np.int64)
    assert t.size == 1021  # every step but the first (0 -> 1023) lies inside a bucket
    bits = np.concatenate([t + k for k in range(-4, 5)])
    rnd = 10.0 ** np.random.default_rng(9).uniform(-40, 38, 200_000)
    d = np.concatenate([bits.astype(np.int32).view(np.float32), rnd.astype(np.float32),
                        np.float32([0.0, 1e-45, 1e30, 2e30, 3e38, np.inf])])
    d64 = d.astype(np.float64)
    want = np.clip(np.floor(1023.0 / (1.0 + np.power(np.minimum(d64, 1e30), 0.33))), 1, 1023)
    got = fsr3.depth_priority(torch.from_numpy(d)[None]).view(-1).numpy()
    assert np.array_equal(got, want)
    assert set(np.unique(got)) == set(range(1, 1024))


@pytest.mark.parametrize("h,w", [(1080, 1920), (37, 53), (1, 1)])
def test_luma8_is_the_reference(h, w):
    """FfxOpticalFlow's 8-bit luminance: the kernel gives the reference's values bit for
    bit: every rounding boundary k + 1/2 of 255 sRGB(Y) hit from both sides, the linear
    segment and its threshold, NaN / inf / negative / -0.0 / HDR colours."""
    from fgcli.ops import color as C
    from fgcli.ops import fsr3

    g = torch.Generator().manual_seed(h + w)
    n = h * w
    c = torch.rand(3, h, w, generator=g)
    # grey values whose encoding lies within a few ulps of each rounding boundary
    k = torch.arange(256, dtype=torch.float64)
    lin = C.srgb_eotf(((k + 0.5) / 255.0).clamp(max=1.0).to(torch.float32)).to(torch.float32)
    near = torch.cat([torch.nextafter(lin, torch.full_like(lin, s)) for s in (-1.0, 2.0)] +
                     [lin, lin * 1.0000002, lin * 0.9999998,
                      torch.tensor([0.0031308, 0.0031307, 0.0031309, 1.0, 0.99999994])])
    m = min(n, near.numel())
    flat = c.view(3, -1)
    flat[:, :m] = near[:m]  # grey: Y == the value up to the luma weights' rounding
    specials = torch.tensor([[NAN, INF, -INF, -0.0, -1.0, 1e30, -1e30, 5.0],
                             [0.0, 0.0, 0.0, -0.0, 0.5, 1e30, 0.2, 0.0],
                             [0.0, 0.0, INF, -0.0, 0.5, 1e30, 0.2, -INF]])
    q = min(n - m, specials.shape[1])
    flat[:, m:m + q] = specials[:, :q]
    k_out, r_out = K.luma8(c), fsr3.luma8(c)
    assert torch.equal(k_out.view(torch.int32), r_out.view(torch.int32))
    # the bytes the block search reads: the same values
    k8, r8 = K.luma8_u8(c), fsr3.luma8_u8(c)
    assert k8.dtype == r8.dtype == torch.uint8
    assert torch.equal(k8, r8) and torch.equal(k8.float(), r_out)
    # from the field's luminance plane (the optical-flow stage's frame 0): the same bytes
    lum = fsr3.field_luminance(c)
    kp, rp = K.luma8_u8_of(lum), fsr3.luma8_u8_of(lum)
    assert kp.dtype == rp.dtype == torch.uint8
    assert torch.equal(kp, r8) and torch.equal(rp, r8)
    if n >= 600:  # the boundaries were hit: both neighbours of some k + 1/2
        assert len(set(r_out.view(-1)[:m].tolist())) > 200


def test_luma8_rounds_exactly():
    """luma8's table is 255 sRGB(Y) rounded to nearest in exact arithmetic (float64 here):
    every threshold and its 4 float32 neighbours each side, 200k random values in [0, 1],
    the linear segment's end, 0, -0.0 and 1 (all 1.07e9 float32 in [0, 1] were checked the
    same way once: no difference)."""
    import numpy as np

    from fgcli.ops import fsr3

    base, thr, b0 = fsr3.luma8_table()
    t = thr[np.isfinite(thr)].view(np.int32).astype(np.int64)
    assert t.size == 255  # every code boundary lies inside a bucket
    bits = np.concatenate([t + d for d in range(-4, 5)])
    rnd = np.random.default_rng(8).random(200_000, dtype=np.float32)
    y = np.concatenate([bits.astype(np.int32).view(np.float32), rnd,
                        np.float32([0.0031308, 0.0031307, 0.0, -0.0, 1.0, 0.99999994, 1e-30])])
    got = fsr3.luma8(torch.from_numpy(np.stack([y, y, y]))[:, None, :]).view(-1).numpy()
    # (a grey colour's Y is y up to the luma weights' rounding: compare at the Y luma8 saw)
    yy = (torch.from_numpy(y) * 0.2126 + torch.from_numpy(y) * 0.7152) + \
        torch.from_numpy(y) * 0.0722
    y64 = yy.clamp(0, 1).numpy().astype(np.float64)
    e = 255.0 * np.minimum(12.92 * y64, 1.055 * np.power(y64, 1 / 2.4) - 0.055)
    want = np.clip(np.floor(e + 0.5), 0, 255)
    assert np.array_equal(got, want)
    assert set(np.unique(got)) == set(range(256))


@pytest.mark.parametrize("h,w", [(37, 53), (36, 52), (1, 5), (5, 1), (2, 2), (64, 3)])
@pytest.mark.parametrize("mode", ["first", "blend"])
def test_pyramid_inpaint_dense_part(h, w, mode):
    """The one-pass dense part (sanitised copy, cleaned weight, holes, level 1 straight
    from the image) against the reference bit for bit: holes given or derived from the
    weight (NaN, +-inf, negative, -0.0 and tiny weights), NaN / inf / HDR values, odd
    edges, no holes, all holes."""
    from fgcli.ops import pyramid

    g = torch.Generator().manual_seed(h * 7 + w)
    v = torch.randn(3, h, w, generator=g) * torch.rand(3, h, w, generator=g) * 100
    v.view(-1)[::11] = float("nan")
    v.view(-1)[::13] = INF
    v.view(-1)[::17] = -INF
    v.view(-1)[::19] = -0.0
    v.view(-1)[::23] = 3e37
    wt = torch.rand(1, h, w, generator=g)
    wt.view(-1)[::5] = 0.0
    wt.view(-1)[::6] = float("nan")
    wt.view(-1)[::7] = -0.5
    wt.view(-1)[::9] = INF
    wt.view(-1)[::10] = -INF
    wt.view(-1)[::12] = -0.0
    wt.view(-1)[::14] = 1e-30
    holes = torch.rand(1, h, w, generator=g) < 0.3
    for vals, wgt, hl in ((v, wt, None), (v, wt, holes), (v[:2], wt, holes),
                          (v, torch.ones(1, h, w), None), (v, torch.zeros(1, h, w), None),
                          (v, wt, torch.zeros(1, h, w, dtype=torch.bool)),
                          (v, wt, torch.ones(1, h, w, dtype=torch.bool))):
        k = K.pyramid_inpaint(vals, wgt, hl, mode=mode)
        r = pyramid.pyramid_inpaint(vals, wgt, hl, mode=mode)
        same_result("pyramid_inpaint", k, r, C["pyramid_inpaint"])
        zero_signs_alike("pyramid_inpaint", k[0], r[0])


@pytest.mark.parametrize("h,w", [(37, 53), (1, 5), (64, 3)])
def test_inpaint_color_in_place(h, w):
    """FSR 3's colour inpainting in place (in_place=True on a colour marked scratch, as the
    interpolation's is): the reference's result bit for bit, written into the colour
    itself (NaN / inf / -0.0 / HDR values sanitised on the rows that hold them, clean rows
    left as they are); an unmarked colour or in_place=False leaves the input alone; no
    holes, all holes."""
    from fgcli.ops import fsr3
    from fgcli.ops._util import mark_scratch

    g = torch.Generator().manual_seed(h * 5 + w)
    v = torch.rand(3, h, w, generator=g) * 4.0
    v[:, 0, 0] = -0.0
    v.view(-1)[:: max(7, w * 2 + 1)] = float("nan")
    v.view(-1)[3:: max(9, w * 3 + 2)] = INF
    v.view(-1)[5:: max(11, w * 4 + 3)] = 3e37
    holes = torch.rand(1, h, w, generator=g) < 0.3
    for hl in (holes, torch.zeros(1, h, w, dtype=torch.bool),
               torch.ones(1, h, w, dtype=torch.bool)):
        ref = fsr3.inpaint_color(v, hl)
        for mark in (True, False):
            for inp in (True, False):
                x = v.clone()
                if mark:
                    mark_scratch(x)
                got = K.inpaint_color(x, hl, in_place=inp)
                same("inpaint in place", got, ref, C["inpaint_color"])
                zero_signs_alike("inpaint in place", got, ref)
                if mark and inp:
                    assert got.data_ptr() == x.data_ptr()
                else:
                    assert got.data_ptr() != x.data_ptr()
                    assert torch.equal(x.view(torch.int32), v.view(torch.int32))


@pytest.mark.parametrize("h,w", [(37, 53), (72, 128), (5, 9), (1, 1), (2, 3)])
def test_inpaint_takes_the_interpolations_level1(h, w):
    """The interpolation pass makes the colour inpainting's level 1 of its output as it
    writes the rows (interp_window_kernel, with the optical flow on the window-fetch
    CPUs), and the in-place inpainting of that output takes it: the reference's
    interpolation and inpainting bit for bit (odd heights: a last single row; HDR, NaN
    and inf colour, holes from off-screen masks). Changed in place between (colour or
    holes), the inpainting pools the changed frame itself: the reference's result of it."""
    from fgcli.ops import fsr3

    c0, c1, v, d = _fsr3_inputs(h, w, h * 3 + w)
    g = torch.Generator().manual_seed(h + 2 * w)
    of = torch.randn(2, h, w, generator=g) * 3.0
    mp = (torch.rand(1, h, w, generator=g) > 0.3).float()
    mc = (torch.rand(1, h, w, generator=g) > 0.3).float()
    mc[0, : h // 2, : w // 2] = 0.0
    mp[0, : h // 2, : w // 2] = 0.0  # a block of holes
    for change in (None, "colour", "holes", "inference"):
        with torch.inference_mode(change == "inference"):  # (as the runner: no versions)
            kc, kh, _ = K.interpolate_fsr3(c0, c1, v, mp, mc, 0.5, of)
            rc, rh, _ = fsr3.interpolate_fsr3(c0, c1, v, mp, mc, 0.5, of)
        if change == "colour":
            kc[:, -1:] += 1.0
            rc[:, -1:] += 1.0
        elif change == "holes":
            kh[0, -1:, -1:] = True
            rh[0, -1:, -1:] = True
        with torch.inference_mode(change == "inference"):
            got = K.inpaint_color(kc, kh, in_place=True)
            want = fsr3.inpaint_color(rc, rh)
        same(f"inpaint of the interpolation, {change}", got, want, C["inpaint_color"])
        zero_signs_alike(f"inpaint of the interpolation, {change}", got, want)
        assert got.data_ptr() == kc.data_ptr() or h * w == 1  # (in place; 1 x 1: reference)


# ----------------------------------------------------------------------------- dispatch, CLI

def test_dispatch_and_resolve():
    from fgcli.errors import UsageError

    from fgcli.kernels import AUTO_CPU, AUTO_MIN_PIXELS

    assert resolve("auto", "cpu") == AUTO_CPU and resolve("auto", "cuda") == "torch"
    # auto: kernels for production-size frames only (compilation would not pay below)
    assert resolve("auto", "cpu", 1920 * 1080) == AUTO_CPU
    assert resolve("auto", "cpu", AUTO_MIN_PIXELS - 1) == "torch"
    assert resolve("numba", "cpu", 4) == "numba"
    assert resolve("numba", "cpu") == "numba" and resolve("torch", "cpu") == "torch"
    assert resolve("torch", "cpu") == "torch" and resolve("numba", "cpu") == "numba"
    with pytest.raises(UsageError):
        resolve("numba", "cuda")
    with pytest.raises(UsageError):
        resolve("fast", "cpu")
    assert op("splat_motion", {"backend": "numba"}) is K.splat_motion
    assert op("splat_motion", {"backend": "torch"}) is R.splat_motion
    assert op("splat_motion", {}) is R.splat_motion  # no backend key: the reference
    assert op("warp_frames", {"backend": "torch"}) is RF.warp_frames


def test_help_does_not_import_numba():
    code = ("import sys\nfrom fgcli.cli import main\n"
            "try:\n    main(sys.argv[1:])\nexcept SystemExit as e:\n    rc = e.code\n"
            "print('NUMBA' if 'numba' in sys.modules else 'NO-NUMBA', rc)\n")
    for args in (["--help"], ["interpolate", "--help"]):
        r = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True,
                           cwd=ROOT, timeout=60)
        assert r.stdout.strip().endswith("NO-NUMBA 0"), (args, r.stdout, r.stderr)


def test_interpolate_backend_recorded(tmp_path):
    import json

    from fgcli.cli import main

    src = os.path.join(ROOT, "sample_data", "blade", "input")
    outs = {}
    for b in ("torch", "numba"):
        out = tmp_path / b
        with pytest.raises(SystemExit) as e:
            main(["interpolate", src, str(out), "--frames", "0-4x2", "--backend", b,
                  "--no-progress"])
        assert e.value.code in (0, None)
        run = json.loads((out / "fgen-run.json").read_text())
        assert run["backend"] == b
        # the kernels are loaded (compiled on a first run) once, before the first frame
        assert (run["kernel_load_ms"] is None) == (b == "torch")
        outs[b] = sorted(p.name for p in out.glob("*.exr"))
    assert outs["torch"] == outs["numba"] and outs["numba"]
    from fgcli.io.frames import read_frame

    for name in outs["numba"]:
        a = read_frame(str(tmp_path / "torch" / name), 1)
        b = read_frame(str(tmp_path / "numba" / name), 1)
        for k in ("color", "depth", "mv"):
            same(f"{name} {k}", getattr(b, k), getattr(a, k), HALF_OUTPUT)


def test_wide_vectors_are_set_before_the_first_kernel_is_compiled():
    """On an AVX-512 host the kernels compile for 512-bit vectors (fgcli.kernels._common):
    numba fixes its target machine at its first @njit, so the setting must be in the
    compiler the kernels actually used."""
    import llvmlite.binding as ll
    from numba.core.registry import cpu_target

    from fgcli.kernels import _common

    feats = getattr(cpu_target.target_context.codegen(), "_tm_features", None)
    if feats is None:
        pytest.skip("numba internals moved")
    assert _common.WIDE_VECTORS == feats.endswith(",-prefer-256-bit")
    user_choice = os.environ.get("NUMBA_CPU_NAME") or os.environ.get("FGEN_VECTOR_WIDTH")
    if not user_choice and "+avx512f" in ll.get_host_cpu_features().flatten().split(","):
        assert _common.WIDE_VECTORS
    # the opt-out
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_CPU")}
    env["FGEN_VECTOR_WIDTH"] = "256"
    out = subprocess.run([sys.executable, "-c", "from fgcli.kernels import _common; "
                          "print(_common.WIDE_VECTORS)"], env=env, capture_output=True,
                         text=True, check=True)
    assert out.stdout.strip() == "False"


def test_any_nonzero_matches_the_reference():
    # frame_facts' motion test: the early-exit kernel against count_nonzero (NaN and -0.0
    # included, non-contiguous views)
    z = torch.zeros(2, 5, 7)
    cases = [z, -z, z.clone().index_put_((torch.tensor([1]), torch.tensor([4]),
                                          torch.tensor([6])), torch.tensor(1e-30)),
             torch.full((2, 3, 3), NAN), torch.randn(2, 4, 4), z[:, :, ::2], z.double()]
    for t in cases:
        assert K.any_nonzero(t) == bool(torch.count_nonzero(t) > 0), t


@pytest.mark.slow
def test_warm_fills_a_cold_cache_and_loads_a_warm_one(tmp_path):
    # an install whose numba cache lacks some kernels (a fresh one lacks all; compiling all
    # takes minutes, so this starts from a copy of the session's cache less two kernels):
    # warm() reads the cache as cold, compiles what is missing, split between two
    # processes, and a second process then only loads (no cache misses)
    import shutil

    from fgcli.kernels import splat

    assert not K._cache_cold()  # the session fixture compiled everything: a full copy
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path))
    r = subprocess.run([sys.executable, "-c", "from fgcli.kernels import splat; "
                        "print(splat.splat_kernel._cache._cache_path)"], env=env,
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    dst = r.stdout.strip()
    src = splat.splat_kernel._cache._cache_path
    gone = ("splat.splat_kernel-", "fill.gap_fill_kernel-")
    shutil.copytree(src, dst, dirs_exist_ok=True,
                    ignore=lambda d, names: [n for n in names if n.startswith(gone)])
    assert any(n.startswith("warp.") for n in os.listdir(dst))
    code = ("from fgcli.kernels import ops, splat, warp, blend, fill; "
            "cold = ops._cache_cold({'core'}); ops.warm(families={'core'}); "
            "ks = (splat.splat_kernel, warp.warp_kernel, blend.blend_kernel, "
            "fill.gap_fill_kernel, warp.mv_warp_kernel, fill.extrap_fill_kernel); "
            "print(cold, sum(sum(k.stats.cache_misses.values()) for k in ks), "
            "ops._cache_cold({'core'}))")
    outs = []
    for _ in range(2):
        r = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                           text=True, timeout=900)
        assert r.returncode == 0, r.stderr[-2000:]
        outs.append(r.stdout.split())
    assert outs[0][0] == "True" and outs[0][-1] == "False", outs  # cold, then every index
    assert any(n.startswith(gone[0]) for n in os.listdir(dst))  # written by warm()
    assert outs[1] == ["False", "0", "False"], outs  # the second compiled nothing


def test_warm_tasks_are_shared_by_claim_files(tmp_path, monkeypatch):
    """On a cold cache warm()'s two processes share _TASKS: each runs the next task whose
    claim file it creates first, skips a task the other claimed and the families not asked
    for; without a claims folder every task runs (the final in-process load)."""
    ran = []
    tasks = tuple((fam, (lambda i, k=k: ran.append(k)))
                  for k, fam in enumerate(("core", "fsr3", "core", "gffe", "core")))
    monkeypatch.setattr(K, "_TASKS", tasks)
    (tmp_path / "2").write_text("")  # taken by the other process
    K._warm_tasks(["core", "gffe"], str(tmp_path))
    assert ran == [0, 3, 4]
    assert sorted(os.listdir(tmp_path)) == ["0", "2", "3", "4"]
    ran.clear()
    K._warm_tasks(["core", "gffe"], str(tmp_path))  # every task claimed: none left here
    assert ran == []
    K._warm_tasks(["fsr3"])
    assert ran == [1]
    assert len(K._TASKS) == len(tasks) and all(f in K.FAMILIES for f, _ in tasks)



def test_kernel_cache_stamp_covers_every_kernel_source(tmp_path):
    """A kernel's numba cache stamp covers the kernel source files it inlines helpers and
    intrinsics from: a change to any of them makes every cached kernel stale (numba's own
    stamp, its file's hash only, kept kernels of an unchanged file compiled against old
    helpers). The wrappers' files (ops.py) hold no compiled code and are left out."""
    import shutil

    from numba import njit

    from fgcli.kernels import _common, scene

    src = os.path.dirname(os.path.abspath(_common.__file__))
    d = tmp_path / "kernels"
    shutil.copytree(src, d, ignore=shutil.ignore_patterns("__pycache__"))
    h0 = _common.kernel_sources_hash(str(d))
    assert h0 == _common.kernel_sources_hash(src)
    (d / "ops.py").write_text((d / "ops.py").read_text() + "\n# a wrapper's change\n")
    assert _common.kernel_sources_hash(str(d)) == h0
    (d / "_intrin.py").write_text((d / "_intrin.py").read_text() + "\n# changed\n")
    assert _common.kernel_sources_hash(str(d)) != h0
    assert _common.KERNEL_CACHE_STAMPED
    stamp = scene.scene_luma_kernel._cache._impl.locator.get_source_stamp()
    assert stamp[1] == h0  # the kernel's: every kernel file's hash with its own

    @njit(cache=True)
    def elsewhere(x):  # a function outside the package keeps numba's stamp
        return x

    assert not isinstance(elsewhere._cache._impl.locator.get_source_stamp(), tuple)


def test_cache_cold_reads_a_stale_index_as_cold(monkeypatch):
    # after an upgrade every kernel's index is stale (the stamp above): warm() must then
    # compile them in two processes, not the pipeline one after the other on one core
    from fgcli.kernels import scene

    k = scene.scene_counts_kernel
    monkeypatch.setattr(K, "_warm_kernels", lambda families=None: (k,))
    assert not K._cache_cold()  # the session fixture compiled it
    monkeypatch.setattr(k._cache._cache_file, "_source_stamp", (b"older", b"sources"))
    assert K._cache_cold()

def test_warm_compiles_every_kernel_the_cold_check_asks_for():
    # _cache_cold() lists kernels by CPU (e.g. the mpsadbw block search or the portable one);
    # a listed kernel that warm() never calls would leave the cache "cold" for ever: every
    # run would announce compiling and start a second process
    code = ("from fgcli.kernels import ops; ops.warm(); "
            "print([k.__name__ for fam in ops.FAMILIES for k in ops._warm_kernels({fam}) "
            "if not k.overloads], ops._cache_cold())")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=900, cwd=ROOT)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.split() == ["[]", "False"], r.stdout


def test_a_run_after_warm_compiles_no_new_overload(tmp_path):
    # warm() calls each kernel on 8x8 inputs; a real frame must reach the same overloads
    # (array types and layouts), or its first frame compiles again (the block search once
    # got a non-C prediction array from numpy's fancy index: 2 s inside the first frame)
    src = os.path.join(ROOT, "sample_data", "orbit", "input")
    runs = [["interpolate", "--pipeline", p] for p in ("mob-fgsr", "fsr3-interp", "mv-warp")]
    runs += [["extrapolate", "--pipeline", p] for p in ("mob-fgsr", "gffe-extrap")]
    code = f"""
import os
from fgcli.cli import main
from fgcli.kernels import ops
ops.warm()
ks = [k for fam in ops.FAMILIES for k in ops._warm_kernels({{fam}})]
seen = [set(k.overloads) for k in ks]
for i, (cmd, *rest) in enumerate({runs!r}):
    try:
        main([cmd, {src!r}, os.path.join({str(tmp_path)!r}, str(i)), *rest, "--frames",
              "0-4x2", "--backend", "numba", "--no-progress"])
    except SystemExit as e:
        assert e.code in (0, None), (cmd, rest, e.code)
print([(k.__name__, str(sig)) for k, s in zip(ks, seen) for sig in set(k.overloads) - s])
"""
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=900, cwd=ROOT)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.split("\n")[-2] == "[]", r.stdout[-2000:]


def test_a_run_loads_only_its_pipelines_kernel_families():
    """fgen loads (and on a cold cache compiles) only the kernels a pipeline's stages call:
    mob-fgsr the shared ones, fsr3-interp / gffe-extrap theirs too."""
    from fgcli import pipeline as pl
    from fgcli.kernels.ops import families_of

    fam = {n: families_of([st for _, st in pl.load(n).build(pl.load(n).modes[0])])
           for n in ("mob-fgsr", "mv-warp", "fsr3-interp", "gffe-extrap")}
    assert fam == {"mob-fgsr": {"core"}, "mv-warp": {"core"}, "fsr3-interp": {"core", "fsr3"},
                   "gffe-extrap": {"core", "gffe"}}
    code = ("from fgcli.kernels import ops, fsr3, geom, splat; ops.warm(families={'core'}); "
            "print(len(splat.splat_kernel.overloads), len(fsr3.interp_game_kernel.overloads), "
            "len(geom.project_kernel.overloads))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=900, cwd=ROOT)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.split() == ["1", "0", "0"], r.stdout


def test_cold_cache_is_announced_before_compiling(tmp_path, monkeypatch, capsys):
    # a first run says it is compiling before the pause, not only after it
    from fgcli.cli import main
    from fgcli.kernels import ops as kops

    seen = []
    monkeypatch.setattr(kops, "_cache_cold", lambda families=None: True)
    monkeypatch.setattr(kops, "warm", lambda parallel=True, families=None:
                        seen.append(capsys.readouterr().err) or 0.01)
    src = os.path.join(ROOT, "sample_data", "blade", "input")
    with pytest.raises(SystemExit) as e:
        main(["interpolate", src, str(tmp_path / "o"), "--frames", "0-2x2", "--backend",
              "numba", "--no-progress"])
    assert e.value.code in (0, None)
    assert seen and "compiling the numba CPU kernels" in seen[0]


def test_stages_declare_their_kernels(tmp_path):
    # the runner loads (or compiles) the kernels only for pipelines with a stage that
    # calls them: every stage that dispatches through op() must say so
    import inspect

    from fgcli.cli import main
    from fgcli.stages.base import load_all

    for name, cls in load_all().items():
        calls = 'op("' in inspect.getsource(cls)
        assert cls.uses_kernels == calls, name
    import json

    src = os.path.join(ROOT, "sample_data", "blade", "input")
    with pytest.raises(SystemExit) as e:
        main(["interpolate", src, str(tmp_path / "o"), "--frames", "0-2x2", "--backend",
              "numba", "--pipeline", "repeat", "--no-progress"])
    assert e.value.code in (0, None)
    run = json.loads((tmp_path / "o" / "fgen-run.json").read_text())
    assert run["backend"] == "numba" and run["kernel_load_ms"] is None


def test_scene_change_score_is_the_references_bit_for_bit():
    """The scene-cut histogram score (every frame's facts) by the numba sampling and
    counting equals the torch reference exactly, and so do its two parts: the sampled
    linear luma (hard values: NaN, +-inf, negative, above 1; sizes the stride does not
    divide) and the counts (levels exactly half-way between two bins: round half to
    even)."""
    import numpy as np

    from fgcli.kernels.scene import scene_counts_kernel, scene_luma_kernel
    from fgcli.ops import scene as SC

    g = torch.Generator().manual_seed(3)
    for h, w, stride in ((24, 32, None), (37, 53, None), (37, 53, 3), (200, 310, None),
                         (200, 310, 4), (9, 7, 2)):
        a = torch.rand(3, h, w, generator=g) * 1.4 - 0.2
        b = torch.rand(3, h, w, generator=g) ** 3
        a[0, 0, 0], a[1, 2, 3], a[2, -1, -1], b[0, 1, 1] = NAN, INF, -INF, NAN
        s = SC.score_stride(h, w, 3, stride)
        lum = np.empty((2, -(-h // s), -(-w // s)), dtype=np.float32)
        scene_luma_kernel(a.numpy(), b.numpy(), s, lum)
        want = SC._linear_luma(torch.stack((a[:, ::s, ::s], b[:, ::s, ::s])))
        assert torch.equal(torch.from_numpy(lum), want), (h, w, stride)
        for x, y in ((a, b), (b, a), (a, a)):
            for bins, regions in ((32, 3), (16, 2), (7, 1)):
                want = SC.scene_change_score_tensor(x, y, bins, regions, stride)
                got = K.scene_change_score_tensor(x, y, bins, regions, stride)
                assert torch.equal(got, want), (h, w, stride, bins, regions, got, want)
    for bins, regions in ((32, 3), (16, 2), (7, 1)):
        k = torch.arange(bins, dtype=torch.float32)
        ties = torch.cat([(k + 0.5) / (bins - 1), k / (bins - 1), torch.rand(200, generator=g)])
        ties = ties.clamp(0.0, 1.0)
        n = ties.numel()
        lv = ties[torch.randperm(n, generator=g)[: (n // 6) * 6]].view(1, 6, -1).expand(2, 6, -1)
        lv = lv.contiguous()
        assert bool(((lv * (bins - 1)) % 1 == 0.5).any())  # exact ties are in there
        counts = np.zeros((2, regions * regions, bins), dtype=np.float32)
        scene_counts_kernel(lv.numpy(), bins, regions, counts)
        assert torch.equal(torch.from_numpy(counts), SC._region_counts(lv, bins, regions))


def test_scene_levels_tables_give_torchs_levels(monkeypatch):
    """scene_bins_kernel's level of a sampled luma (its float32 bits through the tables of
    _scene_levels) is torch's round(pow(L, 1/2.2) * (bins - 1)) by both of torch's pow
    paths (the vectorised body and the scalar tail), on every luma of every window around
    a level's edge and on random ones; where the two paths disagree (the reference's level
    would depend on the sample's position) it is left open, and a frame of such samples
    takes the reference's own pow: the score is still the reference's."""
    import numpy as np

    from fgcli.kernels.scene import _level, scene_bins_kernel
    from fgcli.ops import scene as SC

    rng = np.random.default_rng(4)
    for bins in (32, 16, 7):
        lut, lo, tab = K._scene_levels(bins)
        r = tab.shape[1]
        bits = np.concatenate([(lo[:, None] + np.arange(-3, r + 3)[None, :]).reshape(-1),
                               rng.integers(0, 0x3F800000 + 1, 20000),
                               [0, 1, 0x3F800000]]).astype(np.int32)
        x = torch.from_numpy(bits.view(np.float32).copy())
        e, nb = 1.0 / 2.2, bins - 1
        vec = torch.round(torch.pow(torch.cat([x, x[:-x.numel() % 64]]), e)[:x.numel()] * nb)
        sca = torch.round(torch.pow(torch.stack([x, x], 1).reshape(-1)[::2], e) * nb)
        vec, sca = vec.to(torch.int64).numpy(), sca.to(torch.int64).numpy()
        got = np.array([_level(np.int32(b), lut, lo, tab) for b in bits])
        agree = vec == sca
        assert np.array_equal(got[agree], vec[agree]), bins
        assert np.all(got[~agree] == -1), bins
        assert _level(np.float32(-0.0).view(np.int32), lut, lo, tab) == 0
    # a frame whose every sample has a luma the tables leave open (one of this torch's
    # disputed lumas, or where its two paths never disagree, one marked so): the
    # reference's pow
    lut, lo, tab = K._scene_levels(32)
    if not (tab == -1).any():
        tab = tab.copy()
        tab[5, tab.shape[1] // 2] = -1
        monkeypatch.setattr(K, "_scene_levels", lambda bins: (lut, lo, tab))
    k, o = np.argwhere(tab == -1)[0]
    target = np.int32(lo[k] + o).view(np.float32)
    c1, c2 = np.float32(0.7152), np.float32(0.0722)
    g = np.float32(target / c1)  # (0, g, b): luma = 0.7152 g + 0.0722 b, b's step finer
    while c1 * g > target:
        g = np.nextafter(g, np.float32(0), dtype=np.float32)
    b = np.float32((target - c1 * g) / c2)
    for _ in range(256):
        lum = c1 * g + c2 * b
        if lum == target:
            break
        b = np.nextafter(b, np.float32(np.inf if lum < target else 0), dtype=np.float32)
    assert lum == target
    a = torch.zeros(3, 40, 60)
    a[1], a[2] = float(g), float(b)
    b = torch.rand(3, 40, 60, generator=torch.Generator().manual_seed(2))
    counts = np.zeros((2, 9, 32), dtype=np.float32)
    assert scene_bins_kernel(a.numpy(), b.numpy(), 1, lut, lo, tab, 3, 32, counts) == 40 * 60
    assert torch.equal(K.scene_change_score_tensor(a, b, stride=1),
                       SC.scene_change_score_tensor(a, b, stride=1))
    counts[:] = 0
    assert scene_bins_kernel(b.numpy(), b.numpy(), 1, lut, lo, tab, 3, 32, counts) == 0


def test_brightness_bounds_decide_as_the_table(monkeypatch):
    """The blend kernel decides most of Eq. 1's brightness tests by slope bounds instead of
    the x^(1/2.4) table; the bounds may decide only where the table agrees, so the output
    is bit-identical with the bounds switched off (every test by the table). Differences
    spread log-uniformly over six decades put many pixels next to each t_b."""
    g = torch.Generator().manual_seed(8)
    h, w = 96, 160
    c0 = torch.rand(3, h, w, generator=g) * 1.3 - 0.05
    scale = 10.0 ** (torch.rand(1, h, w, generator=g) * 6 - 6)
    c1 = c0 + torch.randn(3, h, w, generator=g) * scale
    c0[0, 0, 0], c1[1, 0, 1], c0[2, 1, 1], c1[0, 2, 2] = NAN, INF, -INF, 2.0
    d = torch.rand(1, h, w, generator=g) * 5 + 1
    v = torch.ones(1, h, w, dtype=torch.bool)
    for tb in (0.0, 0.003, 0.02, 0.13, 0.4, 2.0):
        for a in (0.3, 0.5, 0.7):
            args = (c0, c1, d, d.clone(), v, v, None, a, 0.02, tb)
            monkeypatch.setattr(K, "BRIGHT_BOUNDS", True)
            got = K.blend_interp(*args, return_depth=True)
            monkeypatch.setattr(K, "BRIGHT_BOUNDS", False)
            want = K.blend_interp(*args, return_depth=True)
            for x, y in zip(got, want):
                assert torch.equal(x, y), (tb, a, int((x != y).sum()))
