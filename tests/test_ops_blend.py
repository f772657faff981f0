"""fgcli.ops.blend: blend_interp (Mob-FGSR Eq. 1), blend_linear; fgcli.ops.color."""
import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from fgcli.ops import (blend_interp, blend_interp_depth, blend_linear, brightness_difference, luminance, mulaw,
                       srgb_eotf, srgb_oetf, to_display)

INF = float("inf")
NAN = float("nan")


def px(*vals):
    """(C, 1, n) tensor from per-pixel tuples."""
    return torch.tensor(vals, dtype=torch.float32).T.reshape(len(vals[0]), 1, len(vals))


def d(*vals):
    return torch.tensor(vals, dtype=torch.float32).view(1, 1, -1)


def b(*vals):
    return torch.tensor(vals).view(1, 1, -1)


def test_eq1_cases():
    # pixel: 0 only frame-0 valid, 1 only frame-1 valid, 2 disocclusion (bg in frame 1),
    # 3 disocclusion (bg in frame 0), 4 same surface + same colour, 5 shading change,
    # 6 both off-screen
    c0 = px((0.1, 0.1, 0.1), (0.1, 0.1, 0.1), (5.0, 0, 0), (0.3, 0.3, 0.3), (0.50, 0.5, 0.5),
            (0.0, 0.0, 0.0), (0.2, 0.2, 0.2))
    c1 = px((0.9, 0.9, 0.9), (0.9, 0.9, 0.9), (0.3, 0.3, 0.3), (5.0, 0, 0), (0.51, 0.5, 0.5),
            (1.0, 1.0, 1.0), (0.8, 0.8, 0.8))
    d0 = d(1, 1, 2.0, 10.0, 4.0, 4.0, 1)
    d1 = d(1, 1, 10.0, 2.0, 4.01, 4.0, 1)
    v0 = b(True, False, True, True, True, True, False)
    v1 = b(False, True, True, True, True, True, False)
    for alpha, near in ((0.3, c0), (0.7, c1)):
        out = blend_interp(c0, c1, d0, d1, v0, v1, alpha=alpha)
        assert torch.equal(out[..., 0], c0[..., 0]) and torch.equal(out[..., 1], c1[..., 1])
        assert torch.equal(out[..., 2], c1[..., 2])  # background from frame 1
        assert torch.equal(out[..., 3], c0[..., 3])  # background from frame 0
        assert torch.equal(out[..., 4], near[..., 4])  # similar: temporally nearer
        assert torch.allclose(out[..., 5], torch.full((3, 1), alpha))  # lerp
        assert torch.equal(out[..., 6], near[..., 6])


def test_alpha_half_takes_frame0_and_endpoints_exact():
    c0 = torch.rand(3, 4, 4)
    c1 = c0 + 0.01
    dd = torch.ones(1, 4, 4)
    v = torch.ones(1, 4, 4, dtype=torch.bool)
    assert torch.equal(blend_interp(c0, c1, dd, dd, v, v, alpha=0.5), c0)
    # endpoints: the rendered frame, whatever the depths say
    dfar = dd * 100
    assert torch.equal(blend_interp(c0, c1, dd, dfar, v, v, alpha=0.0), c0)
    assert torch.equal(blend_interp(c0, c1, dfar, dd, v, ~v, alpha=1.0), c1)


def test_depth_agreement_is_relative_and_inf_aware():
    c0 = px((1.0, 1.0, 1.0), (1.0, 1.0, 1.0), (1.0, 1.0, 1.0))
    c1 = px((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    v = b(True, True, True)
    d0 = d(1000.0, INF, INF)
    d1 = d(1010.0, INF, 5.0)  # 1 % apart: agree; sky/sky agree; sky vs geometry: farther
    out = blend_interp(c0, c1, d0, d1, v, v, alpha=0.5, t_d_rel=0.02)
    assert torch.allclose(out[..., 0], torch.full((3, 1), 0.5))  # agree, colours differ
    assert torch.allclose(out[..., 1], torch.full((3, 1), 0.5))
    assert torch.equal(out[..., 2], c0[..., 2])  # sky is farther
    out = blend_interp(c0, c1, d0, d1, v, v, alpha=0.5, t_d_rel=0.001)
    assert torch.equal(out[..., 0], c1[..., 0])  # now a disocclusion: farther = frame 1


def test_target_depth_preference():
    c0 = px((1.0, 0, 0))
    c1 = px((0, 1.0, 0))
    v = b(True)
    out = blend_interp(c0, c1, d(2.0), d(10.0), v, v, alpha=0.5)
    assert torch.equal(out, c1)  # Eq. 1: farther
    out = blend_interp(c0, c1, d(2.0), d(10.0), v, v, d_target=d(2.01), alpha=0.5)
    assert torch.equal(out, c0)  # the sample on the splatted surface


def test_brightness_difference_and_threshold():
    c0 = px((0.2, 0.2, 0.2))
    c1 = px((0.2, 0.25, 0.2))
    bd = brightness_difference(c0, c1)
    expect = float(srgb_oetf(torch.tensor(0.25)) - srgb_oetf(torch.tensor(0.2)))
    assert math.isclose(float(bd), expect, rel_tol=1e-5)
    v = b(True)
    out = blend_interp(c0, c1, d(1.0), d(1.0), v, v, alpha=0.4, t_b=expect * 1.01)
    assert torch.equal(out, c0)
    out = blend_interp(c0, c1, d(1.0), d(1.0), v, v, alpha=0.4, t_b=expect * 0.99)
    assert torch.allclose(out, torch.lerp(c0, c1, 0.4))


def test_any_channel_count():
    c0 = torch.rand(5, 3, 3)
    c1 = torch.rand(5, 3, 3)
    v = torch.ones(1, 3, 3, dtype=torch.bool)
    out = blend_interp(c0, c1, torch.ones(1, 3, 3), torch.ones(1, 3, 3), v, v, alpha=0.2)
    assert out.shape == (5, 3, 3)


def test_blend_bad_input():
    c = torch.rand(3, 2, 2)
    dd = torch.ones(1, 2, 2)
    v = torch.ones(1, 2, 2, dtype=torch.bool)
    with pytest.raises(ValueError, match="d1_sample"):
        blend_interp(c, c, dd, torch.ones(1, 2, 3), v, v)
    with pytest.raises(TypeError, match="valid0"):
        blend_interp(c, c, dd, dd, dd, v)
    with pytest.raises(ValueError, match="c1_sample"):
        blend_interp(c, torch.rand(4, 2, 2), dd, dd, v, v)
    with pytest.raises(ValueError, match="alpha"):
        blend_interp(c, c, dd, dd, v, v, alpha=2.0)
    with pytest.raises(ValueError, match="t_b"):
        blend_interp(c, c, dd, dd, v, v, t_b=-1.0)
    with pytest.raises(ValueError):
        blend_linear(c, torch.rand(3, 2, 3), 0.5)


def test_blend_linear():
    c0 = torch.rand(2, 3, 4, 4)
    c1 = torch.rand(2, 3, 4, 4)
    assert torch.equal(blend_linear(c0, c1, 0.0), c0)
    assert torch.equal(blend_linear(c0, c1, 1.0), c1)
    assert torch.allclose(blend_linear(c0, c1, 0.25), 0.75 * c0 + 0.25 * c1)
    bad = c0.clone()
    bad[0, 0, 0, 0] = NAN
    bad[0, 0, 0, 1] = INF
    assert torch.isfinite(blend_linear(bad, c1, 0.5)).all()


@st.composite
def blend_case(draw):
    h = draw(st.integers(1, 5))
    w = draw(st.integers(1, 5))
    g = torch.Generator().manual_seed(draw(st.integers(0, 2 ** 31 - 1)))
    vals = [0.0, 1e-30, 65504.0, INF, -INF, NAN, -1.0]
    ts = [torch.rand(3, h, w, generator=g) * 10, torch.rand(3, h, w, generator=g) * 10,
          torch.rand(1, h, w, generator=g) * 10, torch.rand(1, h, w, generator=g) * 10]
    for t in ts:
        for _ in range(draw(st.integers(0, 3))):
            t[draw(st.integers(0, t.shape[0] - 1)), draw(st.integers(0, h - 1)),
              draw(st.integers(0, w - 1))] = draw(st.sampled_from(vals))
    v0 = torch.rand(1, h, w, generator=g) < 0.7
    v1 = torch.rand(1, h, w, generator=g) < 0.7
    alpha = draw(st.sampled_from([0.0, 1e-7, 0.5, 0.9, 1.0]))
    return (*ts, v0, v1, alpha)


@settings(max_examples=25, deadline=None)
@given(blend_case(), st.booleans())
def test_blend_always_finite(case, with_target):
    c0, c1, d0, d1, v0, v1, alpha = case
    out = blend_interp(c0, c1, d0, d1, v0, v1, d_target=d0 if with_target else None,
                       alpha=alpha)
    assert out.shape == c0.shape and torch.isfinite(out).all()


# ------------------------------------------------------------------ colour

def test_srgb_known_values_and_inverse():
    x = torch.tensor([0.0, 0.0031308, 0.5, 1.0, 2.0, -1.0, NAN, INF])
    y = srgb_oetf(x)
    assert torch.allclose(y[:4], torch.tensor([0.0, 0.04045, 0.735357, 1.0]), atol=1e-5)
    assert y[4] == 1.0 and y[5] == 0.0 and y[6] == 0.0 and y[7] == 1.0
    z = torch.linspace(0, 1, 101)
    assert torch.allclose(srgb_eotf(srgb_oetf(z)), z, atol=1e-6)
    yn = srgb_oetf(x.numpy())
    assert isinstance(yn, np.ndarray) and np.allclose(yn, y.numpy(), atol=1e-6)


def test_mulaw_luminance_display():
    assert float(mulaw(torch.tensor(0.0))) == 0.0
    assert math.isclose(float(mulaw(torch.tensor(1.0))), 1.0, rel_tol=1e-6)
    assert math.isclose(float(mulaw(torch.tensor(50.0), peak=100.0)),
                        math.log1p(2500) / math.log1p(5000), rel_tol=1e-5)
    with pytest.raises(ValueError):
        mulaw(torch.tensor(1.0), mu=0)
    y = luminance(torch.ones(3, 2, 2))
    assert y.shape == (1, 2, 2) and torch.allclose(y, torch.ones(1, 2, 2))
    with pytest.raises(ValueError):
        luminance(torch.ones(2, 2, 2))
    with pytest.raises(ValueError, match="transform"):
        to_display(torch.ones(3, 1, 1), "aces")


def test_tune_allocator_is_safe_to_call():
    from fgcli.ops import tune_allocator
    assert tune_allocator() in (True, False)
    assert tune_allocator() in (True, False)


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 6), st.integers(1, 6), st.integers(0, 10_000),
       st.sampled_from([0.0, 0.3, 0.5, 0.7, 1.0]), st.booleans())
def test_blend_return_depth_equals_blend_interp_depth(h, w, seed, alpha, with_target):
    """One pass (colour + depth) gives exactly the colour of blend_interp and the depth of
    blend_interp_depth, for random validity, agreeing/disagreeing depths, sky."""
    g = torch.Generator().manual_seed(seed)
    r = lambda *s: torch.rand(*s, generator=g)  # noqa: E731
    c0, c1 = r(3, h, w), r(3, h, w)
    d0 = torch.where(r(1, h, w) < 0.2, torch.full((1, h, w), float("inf")), 1 + 3 * r(1, h, w))
    d1 = torch.where(r(1, h, w) < 0.5, d0, 1 + 3 * r(1, h, w))
    v0, v1 = r(1, h, w) < 0.8, r(1, h, w) < 0.8
    dt = torch.where(r(1, h, w) < 0.5, d0, d1) if with_target else None
    color, depth = blend_interp(c0, c1, d0, d1, v0, v1, dt, alpha, return_depth=True)
    assert torch.equal(color, blend_interp(c0, c1, d0, d1, v0, v1, dt, alpha))
    assert torch.equal(depth, blend_interp_depth(d0, d1, v0, v1, dt, alpha))
