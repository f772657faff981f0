"""fgcli.ops.fill: gap_fill (Mob-FGSR refinement), extrap_hole_fill, fill_extrap_holes."""
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from fgcli.ops import (SplatResult, extrap_hole_fill, fill_extrap_holes, gap_fill,
                       splat_motion)

INF = float("inf")
NAN = float("nan")


def make_result(depth, valid, to1=None, alpha=0.5, mode="interp"):
    h, w = depth.shape[-2:]
    if to1 is None:
        to1 = torch.zeros(2, h, w)
        to1[0] = torch.arange(h * w, dtype=torch.float32).view(h, w)  # identifies pixels
    to0 = to1 + 1.0
    src = torch.arange(h * w).view(1, h, w).masked_fill(~valid, -1)
    return SplatResult(to1=to1.masked_fill(~valid, 0.0), to0=to0.masked_fill(~valid, 0.0),
                       depth=depth.masked_fill(~valid, INF), valid=valid, source=src,
                       alpha=alpha, mode=mode)


def test_fills_one_pixel_crack_in_surface():
    depth = torch.full((1, 6, 7), 2.0)
    valid = torch.ones(1, 6, 7, dtype=torch.bool)
    valid[0, :, 3] = False  # vertical 1-px crack
    r = make_result(depth, valid)
    f = gap_fill(r)
    assert f.valid.all() and f.filled[0, :, 3].all() and f.filled.sum() == 6
    assert not f.holes.any()
    # each crack pixel copied a neighbour (equal depths: the first in row-major order)
    for y in range(6):
        assert f.source[0, y, 3] == max(y - 1, 0) * 7 + 2
        assert f.to1[0, y, 3] == r.to1[0].view(-1)[f.source[0, y, 3]]
        assert f.depth[0, y, 3] == 2.0
    # inputs untouched
    assert not r.valid[0, :, 3].any() and r.filled is None


def test_replaces_background_leaking_through_crack():
    depth = torch.full((1, 5, 5), 2.0)
    depth[0, :, 2] = 50.0  # far surface splatted through a 1-px crack
    valid = torch.ones(1, 5, 5, dtype=torch.bool)
    f = gap_fill(make_result(depth, valid))
    assert f.filled[0, :, 2].all() and (f.depth[0, :, 2] == 2.0).all()
    assert f.filled.sum() == 5


def test_keeps_edges_and_genuine_disocclusions():
    depth = torch.full((1, 8, 10), 10.0)
    depth[0, :, :4] = 2.0  # near surface on the left: an edge, nothing to fill
    valid = torch.ones(1, 8, 10, dtype=torch.bool)
    valid[0, 2:6, 5:8] = False  # 3-px wide hole in the background: a disocclusion
    f = gap_fill(make_result(depth, valid))
    assert not f.filled.any()
    assert torch.equal(f.holes, ~valid)
    assert torch.equal(f.depth[0, :, :4], depth[0, :, :4])


def test_fallback_linear_motion():
    depth = torch.full((1, 6, 6), 3.0)
    valid = torch.ones(1, 6, 6, dtype=torch.bool)
    valid[0, 1:5, 1:5] = False
    m = torch.zeros(2, 6, 6)
    m[0] = 4.0
    m[1] = -2.0
    fd = torch.full((1, 6, 6), 7.0)
    f = gap_fill(make_result(depth, valid, alpha=0.25), fallback_mv=m, fallback_depth=fd)
    hole = f.holes[0]
    assert hole.sum() == 16
    assert torch.allclose(f.to0[:, hole], torch.tensor([[1.0], [-0.5]]))
    assert torch.allclose(f.to1[:, hole], torch.tensor([[-3.0], [1.5]]))
    assert (f.depth[0][hole] == 7.0).all() and not f.valid[0][hole].any()
    fe = gap_fill(make_result(depth, valid, alpha=0.5, mode="extrap"), fallback_mv=m)
    assert torch.allclose(fe.to1[:, hole], torch.tensor([[2.0], [-1.0]]))
    assert torch.allclose(fe.to0[:, hole], torch.tensor([[6.0], [-3.0]]))


def test_mean_fill():
    depth = torch.full((1, 3, 3), 2.0)
    valid = torch.ones(1, 3, 3, dtype=torch.bool)
    valid[0, :, 1] = False
    to1 = torch.zeros(2, 3, 3)
    to1[0, :, 0] = 1.0
    to1[0, :, 2] = 3.0
    f = gap_fill(make_result(depth, valid, to1=to1), fill="mean")
    assert torch.allclose(f.to1[0, :, 1], torch.full((3,), 2.0))


def test_gap_fill_on_real_splat_and_batch():
    depth = torch.full((1, 10, 12), 5.0)
    yy, xx = torch.meshgrid(torch.arange(10.0), torch.arange(12.0), indexing="ij")
    mv1 = torch.stack([xx * 0.3, yy * 0.0])  # zoom-like spread: grid-like cracks
    r = splat_motion(depth, mv1, None, 0.0)
    assert not r.valid.all()
    f = gap_fill(r)
    assert f.filled.any() and f.valid.sum() > r.valid.sum()
    rb = splat_motion(depth[None].repeat(2, 1, 1, 1), mv1[None].repeat(2, 1, 1, 1), None, 0.0)
    fb = gap_fill(rb)
    assert torch.equal(fb.to1[1], f.to1) and torch.equal(fb.filled[0], f.filled)


def test_gap_fill_bad_input():
    r = make_result(torch.ones(1, 3, 3), torch.ones(1, 3, 3, dtype=torch.bool))
    with pytest.raises(TypeError):
        gap_fill(r.to1)
    with pytest.raises(ValueError, match="fill"):
        gap_fill(r, fill="median")
    with pytest.raises(ValueError, match="fallback_mv"):
        gap_fill(r, fallback_mv=torch.zeros(2, 3, 4))
    with pytest.raises(ValueError, match="depth_threshold_rel"):
        gap_fill(r, depth_threshold_rel=-1)


# ------------------------------------------------------------------ extrapolation holes

def test_extrap_hole_takes_background_motion():
    # frame 1: object (depth 2) at x = 10..15 moving right 4 px/frame (mv -4), bg depth 10.
    h, w = 3, 24
    depth1 = torch.full((1, h, w), 10.0)
    depth1[0, :, 10:16] = 2.0
    mv1 = torch.zeros(2, h, w)
    mv1[0, :, 10:16] = -4.0
    r = splat_motion(depth1, mv1, None, 0.5, "linear", "extrap")  # object at 12..17
    hole = ~r.valid[0]
    assert hole[:, 10:12].all() and hole.sum() == 2 * h
    to1, depth, filled = extrap_hole_fill(mv1, depth1, r.to1, r.valid, r.depth, 0.5)
    # hole q = 10, 11: q + 0.5 * (-4) = 8, 9 is background -> use the vector: sample x = 8, 9
    assert (to1[0, :, 10:12] == -2.0).all() and (depth[0, :, 10:12] == 10.0).all()
    assert torch.equal(filled, ~r.valid)
    assert torch.equal(to1[:, ~hole], r.to1[:, ~hole])


def test_extrap_hole_zero_motion_when_sample_is_nearer():
    h, w = 1, 8
    depth1 = torch.full((1, h, w), 10.0)
    depth1[0, 0, 2] = 1.0  # something near where the vector points
    mv1 = torch.zeros(2, h, w)
    mv1[0, 0, 4] = -2.0
    valid = torch.ones(1, h, w, dtype=torch.bool)
    valid[0, 0, 4] = False
    to1, depth, filled = extrap_hole_fill(mv1, depth1, torch.zeros(2, h, w), valid,
                                          torch.full((1, h, w), INF), 1.0)
    assert to1[0, 0, 4] == 0.0 and depth[0, 0, 4] == 10.0 and filled[0, 0, 4]
    # off-screen sample: zero motion too
    mv1[0, 0, 4] = -100.0
    to1, _, _ = extrap_hole_fill(mv1, depth1, torch.zeros(2, h, w), valid,
                                 torch.full((1, h, w), INF), 1.0)
    assert to1[0, 0, 4] == 0.0


def test_fill_extrap_holes_result():
    h, w = 2, 20
    depth1 = torch.full((1, h, w), 10.0)
    depth1[0, :, 8:12] = 2.0
    mv1 = torch.zeros(2, h, w)
    mv1[0, :, 8:12] = -2.0
    r = gap_fill(splat_motion(depth1, mv1, None, 1.0, "linear", "extrap"))
    f = fill_extrap_holes(r, mv1, depth1)
    assert torch.equal(f.holes, ~r.valid) and torch.isfinite(f.to0).all()
    assert (f.to1[0][f.holes[0]] == -2.0).all()
    with pytest.raises(ValueError, match="extrap"):
        fill_extrap_holes(r.replace(mode="interp"), mv1, depth1)


# ------------------------------------------------------------------ properties

@st.composite
def result_case(draw):
    h = draw(st.integers(1, 6))
    w = draw(st.integers(1, 6))
    g = torch.Generator().manual_seed(draw(st.integers(0, 2 ** 31 - 1)))
    depth = torch.rand(1, h, w, generator=g) * 10
    for _ in range(draw(st.integers(0, 3))):
        depth[0, draw(st.integers(0, h - 1)), draw(st.integers(0, w - 1))] = draw(
            st.sampled_from([0.0, INF, NAN, 1e-30, 1e30]))
    valid = torch.rand(1, h, w, generator=g) < draw(st.sampled_from([0.0, 0.5, 0.9, 1.0]))
    mv = (torch.rand(2, h, w, generator=g) - 0.5) * draw(st.sampled_from([0.0, 10.0, 1e9]))
    mv[0, 0, 0] = draw(st.sampled_from([0.0, NAN, INF]))
    mode = draw(st.sampled_from(["interp", "extrap"]))
    return make_result(depth, valid, alpha=draw(st.sampled_from([0.0, 0.5, 1.0])),
                       mode=mode), mv, depth


@settings(max_examples=25, deadline=None)
@given(result_case(), st.sampled_from(["nearest", "mean"]))
def test_fills_always_finite(case, fill):
    r, mv, depth = case
    f = gap_fill(r, fill=fill, fallback_mv=mv, fallback_depth=depth)
    for t in (f.to1, f.to0):
        assert torch.isfinite(t).all() and t.shape == r.to1.shape
    assert not torch.isnan(f.depth).any()
    assert torch.equal(f.holes, ~f.valid) and not (f.filled & f.holes).any()
    assert (f.valid | ~r.valid).all()  # refinement never removes vectors
    to1, d, filled = extrap_hole_fill(mv, depth, r.to1, r.valid, r.depth, r.alpha)
    assert torch.isfinite(to1).all() and not torch.isnan(d).any()
    assert torch.equal(filled, ~r.valid)
