"""fgcli.ops.warp: backward_warp, sample_nearest, mv-warp baselines."""
import math

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from fgcli.ops import (backward_warp, mv_warp_extrap, mv_warp_interp, repeat_nearest,
                       sample_nearest)

MODES = ["bilinear", "catmull-rom", "nearest"]
BORDERS = ["clamp", "zeros"]
SPECIAL = [0.0, -0.0, 1e-30, 1.0, 65504.0, float("inf"), float("-inf"), float("nan")]


@st.composite
def image_and_flow(draw, max_side=7, channels=None):
    h = draw(st.integers(1, max_side))
    w = draw(st.integers(1, max_side))
    c = channels or draw(st.integers(1, 4))
    g = torch.Generator().manual_seed(draw(st.integers(0, 2 ** 31 - 1)))
    img = torch.rand(c, h, w, generator=g) * draw(st.sampled_from([1.0, 65504.0, 1e-6]))
    for _ in range(draw(st.integers(0, 3))):
        img[draw(st.integers(0, c - 1)), draw(st.integers(0, h - 1)),
            draw(st.integers(0, w - 1))] = draw(st.sampled_from(SPECIAL))
    scale = draw(st.sampled_from([0.0, 0.5, 3.0, 1e3, 1e12]))
    flow = (torch.rand(2, h, w, generator=g) * 2 - 1) * scale
    for _ in range(draw(st.integers(0, 2))):
        flow[draw(st.integers(0, 1)), draw(st.integers(0, h - 1)),
             draw(st.integers(0, w - 1))] = draw(st.sampled_from(SPECIAL))
    return img, flow


# ------------------------------------------------------------------ smoke / shapes

@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("border", BORDERS)
def test_shapes_and_dtypes(mode, border):
    img = torch.rand(3, 5, 7)
    flow = torch.randn(2, 5, 7)
    out, valid = backward_warp(img, flow, mode, border)
    assert out.shape == (3, 5, 7) and out.dtype == torch.float32
    assert valid.shape == (1, 5, 7) and valid.dtype == torch.bool


@pytest.mark.parametrize("mode", MODES)
def test_batched_equals_per_frame(mode):
    img = torch.rand(2, 3, 6, 5)
    flow = torch.randn(2, 2, 6, 5) * 2
    out, valid = backward_warp(img, flow, mode)
    assert out.shape == (2, 3, 6, 5) and valid.shape == (2, 1, 6, 5)
    for i in range(2):
        o, v = backward_warp(img[i], flow[i], mode)
        assert torch.equal(o, out[i]) and torch.equal(v, valid[i])


def test_does_not_modify_inputs():
    img = torch.rand(3, 4, 4)
    img[0, 0, 0] = float("nan")
    flow = torch.randn(2, 4, 4)
    flow[0, 1, 1] = float("nan")
    i0, f0 = img.clone(), flow.clone()
    for mode in MODES:
        backward_warp(img, flow, mode, "zeros")
    assert torch.equal(img.nan_to_num(7.0), i0.nan_to_num(7.0))
    assert torch.equal(flow.nan_to_num(7.0), f0.nan_to_num(7.0))


# ------------------------------------------------------------------ bad input

@pytest.mark.parametrize("img,flow,msg", [
    (torch.rand(4, 4), torch.zeros(2, 4, 4), "img"),
    (torch.rand(3, 4, 4), torch.zeros(3, 4, 4), "flow"),
    (torch.rand(3, 4, 4), torch.zeros(2, 4, 5), "size"),
    (torch.rand(2, 3, 4, 4), torch.zeros(2, 4, 4), "rank"),
    (torch.rand(3, 0, 4), torch.zeros(2, 0, 4), "empty"),
])
def test_bad_shapes_raise(img, flow, msg):
    with pytest.raises(ValueError, match=msg):
        backward_warp(img, flow)


def test_bad_options_raise():
    with pytest.raises(ValueError, match="mode"):
        backward_warp(torch.rand(3, 2, 2), torch.zeros(2, 2, 2), mode="cubic")
    with pytest.raises(ValueError, match="border"):
        backward_warp(torch.rand(3, 2, 2), torch.zeros(2, 2, 2), border="wrap")
    with pytest.raises(TypeError):
        backward_warp([[1.0]], torch.zeros(2, 2, 2))


# ------------------------------------------------------------------ known answers

@pytest.mark.parametrize("mode", MODES)
def test_integer_shift(mode):
    img = torch.rand(3, 6, 8) * 100
    flow = torch.zeros(2, 6, 8)
    flow[0] = 2.0  # read two pixels to the right
    flow[1] = -1.0  # and one up
    out, valid = backward_warp(img, flow, mode)
    assert torch.allclose(out[:, 1:, :6], img[:, :5, 2:], atol=1e-3, rtol=1e-5)
    assert valid[0, 1:, :6].all()
    assert not valid[0, 0].any() and not valid[0, :, 6:].any()
    # clamp border replicates the edge
    assert torch.allclose(out[:, 1:, 7], img[:, :5, 7], atol=1e-3, rtol=1e-5)


def test_bilinear_half_pixel_is_average():
    img = torch.tensor([[[0.0, 2.0, 10.0]]])
    flow = torch.zeros(2, 1, 3)
    flow[0] = 0.5
    out, valid = backward_warp(img, flow)
    assert torch.allclose(out[0, 0, :2], torch.tensor([1.0, 6.0]), atol=1e-3)
    assert valid[0, 0].tolist() == [True, True, False]  # x = 3.0 is outside [0, 3)


def test_nearest_rounds_half_up_and_zeros_border():
    img = torch.arange(5.0).view(1, 1, 5)
    flow = torch.full((2, 1, 5), 0.0)
    flow[0] = 0.5
    out, _ = backward_warp(img, flow, "nearest")
    assert out[0, 0].tolist() == [1.0, 2.0, 3.0, 4.0, 4.0]
    out, valid = backward_warp(img, flow * 20, "nearest", "zeros")
    assert out[0, 0].tolist() == [0.0, 0.0, 0.0, 0.0, 0.0] and not valid.any()


def test_catmull_rom_reproduces_linear_ramp_and_does_not_ring():
    x = torch.arange(12.0)
    img = (x * 3.0 + 1.0).view(1, 1, 12).expand(1, 4, 12).clone()
    flow = torch.zeros(2, 4, 12)
    flow[0] = 0.3
    out, _ = backward_warp(img, flow, "catmull-rom")
    assert torch.allclose(out[0, :, 1:9], img[0, :, 1:9] + 0.9, atol=1e-4)
    step = torch.zeros(1, 1, 10)
    step[..., 5:] = 65504.0
    flow = torch.zeros(2, 1, 10)
    flow[0] = 0.4
    out, _ = backward_warp(step, flow, "catmull-rom")
    assert out.min() >= 0.0 and out.max() <= 65504.0


def test_zeros_border_reads_zero_outside():
    img = torch.ones(1, 3, 3)
    flow = torch.full((2, 3, 3), 100.0)
    for mode in MODES:
        out, valid = backward_warp(img, flow, mode, "zeros")
        assert torch.equal(out, torch.zeros(1, 3, 3)) and not valid.any()


def test_sample_nearest_keeps_inf():
    d = torch.tensor([[[1.0, float("inf"), float("nan")]]])
    flow = torch.zeros(2, 1, 3)
    flow[0, 0, 0] = 1.0
    out, valid = sample_nearest(d, flow)
    assert out[0, 0, 0] == float("inf") and out[0, 0, 1] == float("inf")
    assert out[0, 0, 2] == float("inf") and valid.all()


# ------------------------------------------------------------------ properties

@settings(max_examples=25, deadline=None)
@given(image_and_flow())
def test_zero_flow_is_identity(case):
    img, _ = case
    img = img.nan_to_num(0.0).clamp(-1e30, 1e30)
    for mode in MODES:
        for border in BORDERS:
            out, valid = backward_warp(img, torch.zeros(2, *img.shape[1:]), mode, border)
            assert torch.equal(out, img), (mode, border)
            assert valid.all()


@settings(max_examples=25, deadline=None)
@given(image_and_flow())
def test_output_always_finite(case):
    img, flow = case
    for mode in MODES:
        for border in BORDERS:
            out, valid = backward_warp(img, flow, mode, border)
            assert torch.isfinite(out).all(), (mode, border)
            assert out.shape == img.shape and valid.shape == (1, *img.shape[1:])
            assert not valid[0][torch.isnan(flow).any(0)].any()


# ------------------------------------------------------------------ baselines

def test_mv_warp_interp_endpoints_and_motion():
    c0 = torch.rand(3, 5, 9)
    c1 = torch.rand(3, 5, 9)
    mv1 = torch.zeros(2, 5, 9)
    mv1[0] = -2.0  # content moved right by 2 px from frame 0 to frame 1
    assert torch.equal(mv_warp_interp(c0, c1, mv1, 0.0), c0)
    assert torch.equal(mv_warp_interp(c0, c1, mv1, 1.0), c1)
    mid = mv_warp_interp(c0, c1, mv1, 0.5)  # frame 0 shifted right by 1
    assert torch.allclose(mid[:, :, 1:], c0[:, :, :-1], atol=1e-4)
    late = mv_warp_interp(c0, c1, mv1, 0.75)  # frame 1 shifted left by 0.5
    assert torch.allclose(late[:, :, :-1], 0.5 * (c1[:, :, :-1] + c1[:, :, 1:]), atol=1e-4)
    assert torch.equal(mv_warp_extrap(c1, mv1, 0.0), c1)
    ext = mv_warp_extrap(c1, mv1, 1.0)  # keeps moving right by 2
    assert torch.allclose(ext[:, :, 2:], c1[:, :, :-2], atol=1e-4)


def test_repeat_nearest():
    c0, c1 = torch.zeros(3, 2, 2), torch.ones(3, 2, 2)
    assert torch.equal(repeat_nearest(c0, c1, 0.5), c0)
    assert torch.equal(repeat_nearest(c0, c1, 0.51), c1)
    out = repeat_nearest(c0, c1, 0.0)
    assert out is not c0


def test_baselines_bad_alpha():
    c = torch.rand(3, 2, 2)
    with pytest.raises(ValueError, match="alpha"):
        mv_warp_interp(c, c, torch.zeros(2, 2, 2), 1.5)
    with pytest.raises(ValueError, match="alpha"):
        mv_warp_extrap(c, torch.zeros(2, 2, 2), -0.1)
    with pytest.raises(ValueError, match="alpha"):
        repeat_nearest(c, c, math.nan)
