"""fgcli.ops.splat: dilate_nearest_depth, splat_motion, generated_mv."""
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from fgcli.ops import (SplatResult, dilate_nearest_depth, generated_mv, motion_coefficients,
                       splat_motion)

INF = float("inf")
NAN = float("nan")


# ------------------------------------------------------------------ dilation

def test_dilation_spreads_nearest_pixel():
    depth = torch.full((1, 5, 5), 10.0)
    mv = torch.zeros(2, 5, 5)
    depth[0, 2, 2] = 1.0
    mv[:, 2, 2] = torch.tensor([3.0, -1.0])
    d, m = dilate_nearest_depth(depth, mv)
    block = (slice(1, 4), slice(1, 4))
    assert (d[0][block] == 1.0).all() and (m[0][block] == 3.0).all() and (m[1][block] == -1).all()
    assert d[0, 0, 0] == 10.0 and m[0, 0, 0] == 0.0
    d, m = dilate_nearest_depth(depth, mv, radius=2)
    assert (d == 1.0).all() and (m[0] == 3.0).all()


def test_dilation_ties_keep_centre_and_sky():
    depth = torch.full((1, 3, 4), 5.0)
    mv = torch.arange(24.0).view(2, 3, 4)
    d, m = dilate_nearest_depth(depth, mv)
    assert torch.equal(d, depth) and torch.equal(m, mv)  # flat depth: nothing moves
    sky = torch.full((1, 3, 3), INF)
    sky[0, 0, 0] = 7.0
    d, m = dilate_nearest_depth(sky, mv[:, :, :3])
    assert d[0, 1, 1] == 7.0 and m[0, 1, 1] == mv[0, 0, 0]
    assert d[0, 2, 2] == INF and m[0, 2, 2] == mv[0, 2, 2]  # all-sky window keeps centre


def test_dilation_radius0_shapes_batch_and_bad_input():
    depth = torch.rand(2, 1, 4, 6) + 1
    mv = torch.randn(2, 2, 4, 6)
    d, m = dilate_nearest_depth(depth, mv, 0)
    assert torch.equal(d, depth) and torch.equal(m, mv) and d is not depth
    d, m = dilate_nearest_depth(depth, mv)
    for i in range(2):
        di, mi = dilate_nearest_depth(depth[i], mv[i])
        assert torch.equal(di, d[i]) and torch.equal(mi, m[i])
    with pytest.raises(ValueError, match="radius"):
        dilate_nearest_depth(depth, mv, -1)
    with pytest.raises(ValueError, match="mv"):
        dilate_nearest_depth(depth[0], mv[0, :1])
    with pytest.raises(ValueError, match="depth"):
        dilate_nearest_depth(torch.rand(2, 4, 6), mv[0])


def test_dilation_hard_values():
    depth = torch.tensor([[[0.0, NAN, -3.0], [INF, 1e-30, 2.0]]])
    mv = torch.tensor([[[1.0, 2, 3], [4, 5, 6]], [[0.0, 0, 0], [0, 0, 0]]])
    d, m = dilate_nearest_depth(depth, mv)
    assert torch.isfinite(m).all() and not torch.isnan(d).any() and (d >= 0).all()


# ------------------------------------------------------------------ splat: known answers

def _res_ok(r, h, w):
    assert isinstance(r, SplatResult)
    assert r.to1.shape == (2, h, w) and r.to0.shape == (2, h, w)
    assert r.depth.shape == (1, h, w) and r.valid.shape == (1, h, w)
    assert r.valid.dtype == torch.bool and r.source.dtype == torch.int32
    assert torch.isfinite(r.to1).all() and torch.isfinite(r.to0).all()
    assert not torch.isnan(r.depth).any()


@pytest.mark.parametrize("mode", ["interp", "extrap"])
@pytest.mark.parametrize("model", ["linear", "quadratic"])
def test_zero_motion_is_identity(mode, model):
    depth = torch.rand(1, 5, 6) + 0.5
    z = torch.zeros(2, 5, 6)
    r = splat_motion(depth, z, z, 0.3, model, mode)
    _res_ok(r, 5, 6)
    assert r.valid.all() and torch.equal(r.depth, depth)
    assert (r.to1 == 0).all() and (r.to0 == 0).all()
    assert torch.equal(r.source.view(-1), torch.arange(30, dtype=torch.int32))


def test_linear_interp_constant_motion():
    h, w = 4, 12
    depth = torch.ones(1, h, w)
    mv1 = torch.zeros(2, h, w)
    mv1[0] = -4.0  # moved right by 4 px from frame 0 to frame 1
    r = splat_motion(depth, mv1, None, 0.25)  # p = p1 + 0.75 * (-4) = p1 - 3
    assert r.valid[0, :, :9].all() and not r.valid[0, :, 9:].any()
    assert (r.to1[0][r.valid[0]] == 3.0).all() and (r.to0[0][r.valid[0]] == -1.0).all()
    assert (r.source[0, :, :9] % w == torch.arange(3, 12)).all()
    assert (r.source[~r.valid] == -1).all() and (r.depth[~r.valid] == INF).all()


def test_quadratic_formula_single_pixel():
    h, w = 1, 40
    depth = torch.full((1, h, w), INF)
    mv1 = torch.zeros(2, h, w)
    mv0 = torch.zeros(2, h, w)
    depth[0, 0, 30] = 1.0
    mv1[0, 0, 30] = -8.0  # a: was at x = 22 in frame 0
    mv0[0, 0, 22] = -4.0  # b: was at x = 18 in frame -1 (accelerating)
    alpha = 0.5
    r = splat_motion(depth, mv1, mv0, alpha, "quadratic")
    ca, cb = motion_coefficients(alpha, "quadratic", "interp")
    disp = ca * -8.0 + cb * -4.0  # 0.625 * -8 - 0.125 * -4 = -4.5
    assert disp == -4.5
    tgt = int(torch.floor(torch.tensor(30 + disp + 0.5)))  # 26
    assert r.source[0, 0, tgt] == 30
    assert r.to1[0, 0, tgt] == -disp and r.to0[0, 0, tgt] == -8.0 - disp
    # the parabola through x(-1) = 18, x(0) = 22, x(1) = 30 at t = 0.5 is 25.5
    assert 30 + disp == 25.5
    # a == b reduces to linear
    mv0[0, 0, 22] = -8.0
    rq = splat_motion(depth, mv1, mv0, alpha, "quadratic")
    rl = splat_motion(depth, mv1, None, alpha, "linear")
    tq = (rq.source[0, 0] == 30).nonzero()
    tl = (rl.source[0, 0] == 30).nonzero()
    assert torch.equal(tq, tl) and rq.to1[0, 0, tq] == rl.to1[0, 0, tl] == 4.0


def test_extrapolation_formulas():
    h, w = 1, 40
    depth = torch.full((1, h, w), INF)
    mv1 = torch.zeros(2, h, w)
    mv0 = torch.zeros(2, h, w)
    depth[0, 0, 10] = 1.0
    mv1[0, 0, 10] = -4.0
    mv0[0, 0, 6] = -2.0
    r = splat_motion(depth, mv1, None, 0.5, "linear", "extrap")  # p = 10 + 2 = 12
    assert r.source[0, 0, 12] == 10 and r.to1[0, 0, 12] == -2.0 and r.to0[0, 0, 12] == -6.0
    r = splat_motion(depth, mv1, mv0, 1.0, "quadratic", "extrap")
    # p = p1 - 2 a + 1 b = 10 + 8 - 2 = 16: parabola through 4, 6, 10 at t = 2 is 16
    assert r.source[0, 0, 16] == 10 and r.to1[0, 0, 16] == -6.0
    assert generated_mv(r)[0, 0, 16] == -6.0


def test_nearest_surface_wins_and_ties_are_deterministic():
    h, w = 1, 6
    mv1 = torch.zeros(2, h, w)
    mv1[0, 0, 4] = -4.0  # pixel 4 lands on pixel 0 (linear, alpha=0)
    for near, far in [(1.0, 2.0), (2.0, 1.0)]:
        depth = torch.full((1, h, w), 5.0)
        depth[0, 0, 0] = near
        depth[0, 0, 4] = far
        r = splat_motion(depth, mv1, None, 0.0)
        assert r.source[0, 0, 0] == (0 if near < far else 4)
        assert r.depth[0, 0, 0] == min(near, far)
    depth = torch.full((1, h, w), 5.0)
    r = splat_motion(depth, mv1, None, 0.0)
    assert r.source[0, 0, 0] == 0  # equal depth: lowest source index


def test_depth_ordering_zero_finite_inf():
    mv1 = torch.zeros(2, 1, 3)
    mv1[0, 0, 1] = -1.0
    mv1[0, 0, 2] = -2.0
    for vals, winner in [((INF, 3.0, 0.0), 2), ((INF, 3.0, 4.0), 1), ((1e-30, INF, 1e30), 0)]:
        depth = torch.tensor(vals).view(1, 1, 3)
        r = splat_motion(depth, mv1, None, 0.0)
        assert r.source[0, 0, 0] == winner, vals


def test_everything_into_one_pixel():
    h, w = 5, 7
    yy, xx = torch.meshgrid(torch.arange(h, dtype=torch.float32),
                            torch.arange(w, dtype=torch.float32), indexing="ij")
    mv1 = torch.stack([2.0 - xx, 3.0 - yy])  # every pixel came from (2, 3)
    depth = torch.rand(1, h, w) + 1
    r = splat_motion(depth, mv1, None, 0.0)
    assert r.valid.sum() == 1 and r.valid[0, 3, 2]
    assert r.source[0, 3, 2] == int(depth.view(-1).argmin())
    _res_ok(r, h, w)


def test_endpoints():
    depth = torch.rand(1, 6, 7) + 1
    mv1 = torch.randn(2, 6, 7) * 2
    mv0 = torch.randn(2, 6, 7) * 2
    r = splat_motion(depth, mv1, mv0, 1.0)
    assert r.valid.all() and (r.to1 == 0).all() and torch.equal(r.to0, mv1)
    r = splat_motion(depth, mv1, mv0, 0.0)
    v = r.valid[0]
    src = r.source[0][v]
    assert (r.to0 == 0).all()
    assert torch.equal(r.to1[:, v], -mv1.reshape(2, -1)[:, src])


def test_depth0_check_falls_back_to_linear():
    h, w = 1, 20
    depth1 = torch.full((1, h, w), 10.0)
    depth0 = torch.full((1, h, w), 10.0)
    mv1 = torch.zeros(2, h, w)
    mv0 = torch.zeros(2, h, w)
    mv0[0, 0, 8] = -4.0  # frame 0 shows a different (near) surface at x = 8
    depth0[0, 0, 8] = 1.0
    r = splat_motion(depth1, mv1, mv0, 0.5)  # pixel 8 (static) is pulled by b
    assert r.source[0, 0, 8] != 8
    r = splat_motion(depth1, mv1, mv0, 0.5, depth0=depth0)
    assert r.source[0, 0, 8] == 8 and r.to1[0, 0, 8] == 0.0


def test_batched_and_generated_mv():
    depth = torch.rand(2, 1, 5, 6) + 1
    mv1 = torch.randn(2, 2, 5, 6)
    mv0 = torch.randn(2, 2, 5, 6)
    r = splat_motion(depth, mv1, mv0, 0.4)
    assert r.to1.shape == (2, 2, 5, 6) and r.valid.shape == (2, 1, 5, 6)
    for i in range(2):
        ri = splat_motion(depth[i], mv1[i], mv0[i], 0.4)
        assert torch.equal(ri.to1, r.to1[i]) and torch.equal(ri.source, r.source[i])
    assert torch.equal(generated_mv(r), r.to0)
    with pytest.raises(TypeError):
        generated_mv(r.to0)


@pytest.mark.parametrize("kw,exc,msg", [
    (dict(alpha=1.5), ValueError, "alpha"),
    (dict(alpha=-0.1, mode="extrap"), ValueError, "alpha"),
    (dict(model="cubic"), ValueError, "model"),
    (dict(mode="both"), ValueError, "mode"),
])
def test_bad_options(kw, exc, msg):
    args = dict(depth1=torch.ones(1, 3, 3), mv1=torch.zeros(2, 3, 3), mv0=None, alpha=0.5)
    args.update(kw)
    with pytest.raises(exc, match=msg):
        splat_motion(**args)


def test_bad_shapes():
    with pytest.raises(ValueError, match="mv1"):
        splat_motion(torch.ones(1, 3, 3), torch.zeros(3, 3, 3), None, 0.5)
    with pytest.raises(ValueError, match="mv0"):
        splat_motion(torch.ones(1, 3, 3), torch.zeros(2, 3, 3), torch.zeros(2, 3, 4), 0.5)
    with pytest.raises(ValueError, match="depth1"):
        splat_motion(torch.ones(2, 3, 3), torch.zeros(2, 3, 3), None, 0.5)


# ------------------------------------------------------------------ properties

SPECIAL_D = [0.0, -0.0, -1.0, 1e-30, 1e30, INF, NAN]
SPECIAL_MV = [0.0, 1e9, -1e9, INF, -INF, NAN, 0.5, -0.5]


@st.composite
def splat_case(draw):
    h = draw(st.integers(1, 6))
    w = draw(st.integers(1, 6))
    g = torch.Generator().manual_seed(draw(st.integers(0, 2 ** 31 - 1)))
    depth = torch.rand(1, h, w, generator=g) * 10
    scale = draw(st.sampled_from([0.0, 1.0, 4.0, 100.0]))
    mv1 = (torch.rand(2, h, w, generator=g) * 2 - 1) * scale
    mv0 = (torch.rand(2, h, w, generator=g) * 2 - 1) * scale
    for t, vals in ((depth, SPECIAL_D), (mv1, SPECIAL_MV), (mv0, SPECIAL_MV)):
        for _ in range(draw(st.integers(0, 3))):
            t[draw(st.integers(0, t.shape[0] - 1)), draw(st.integers(0, h - 1)),
              draw(st.integers(0, w - 1))] = draw(st.sampled_from(vals))
    mode = draw(st.sampled_from(["interp", "extrap"]))
    alpha = draw(st.sampled_from([0.0, 1e-6, 0.25, 0.5, 0.999, 1.0] + ([3.0] if mode == "extrap"
                                                                       else [])))
    model = draw(st.sampled_from(["linear", "quadratic"]))
    return depth, mv1, mv0, alpha, model, mode


@settings(max_examples=25, deadline=None)
@given(splat_case())
def test_splat_always_finite(case):
    depth, mv1, mv0, alpha, model, mode = case
    d0, m10, m00 = depth.clone(), mv1.clone(), mv0.clone()
    dd, mm = dilate_nearest_depth(depth, mv1)
    r = splat_motion(dd, mm, mv0, alpha, model, mode, depth0=depth)
    _res_ok(r, *depth.shape[1:])
    assert ((r.source >= 0) == r.valid).all()
    # inputs untouched
    for a, b in ((depth, d0), (mv1, m10), (mv0, m00)):
        assert torch.equal(a.nan_to_num(1.5), b.nan_to_num(1.5))
