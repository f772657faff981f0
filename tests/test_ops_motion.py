"""fgcli.ops.motion: chain_mv, disocclusion_mask."""
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from fgcli.ops import chain_mv, disocclusion_mask

INF = float("inf")


def test_chain_constant_and_varying_motion():
    h, w = 6, 20
    a = torch.zeros(2, h, w)
    a[0] = -2.0
    out = chain_mv([a, a, a])
    assert torch.allclose(out[0, :, 6:], torch.full((h, w - 6), -6.0))
    # frame k: pixel x came from x - 3 in frame k-1, where frame k-1's vectors say -1 (only
    # at x in 5..9): chained vector at x = 10 is -3 + -1
    bk = torch.zeros(2, h, w)
    bk[0, :, 10] = -3.0
    bk1 = torch.zeros(2, h, w)
    bk1[0, :, 5:10] = -1.0
    out = chain_mv([bk, bk1])
    assert torch.allclose(out[0, :, 10], torch.full((h,), -4.0))
    assert torch.allclose(out[0, :, 6], torch.full((h,), -1.0))
    single = chain_mv([bk])
    assert torch.equal(single, bk) and single is not bk


def test_chain_offscreen_and_bad_input():
    a = torch.zeros(2, 3, 4)
    a[0] = -100.0
    b = torch.zeros(2, 3, 4)
    b[0] = 1.0
    out = chain_mv([a, b, torch.full((2, 3, 4), float("nan"))])
    assert torch.isfinite(out).all()
    assert torch.allclose(out[0], torch.full((3, 4), -99.0))  # clamped fetch, keeps going
    with pytest.raises(ValueError, match="non-empty"):
        chain_mv([])
    with pytest.raises(ValueError, match="mv_list"):
        chain_mv([a, torch.zeros(2, 3, 5)])
    with pytest.raises(ValueError):
        chain_mv(a)


def test_disocclusion_mask_moving_square():
    from fgcli.ops._testing import moving_square
    c1, d1, m1 = moving_square(1.0)
    c0, d0, m0 = moving_square(0.0)
    mask = disocclusion_mask(d1, m1, d0)
    assert mask.shape == d1.shape and mask.dtype == torch.bool
    # background at x = 16..19 (rows 8..13) was covered by the square in frame 0
    assert mask[0, 8:14, 16:20].all()
    assert mask.sum() == 6 * 4
    # zero motion, same depth: nothing disoccluded; off-screen vectors: everything
    assert not disocclusion_mask(d0, torch.zeros_like(m0), d0).any()
    assert disocclusion_mask(d0, torch.full_like(m0, 1e9), d0).all()


def test_disocclusion_sky():
    dt = torch.tensor([[[INF, INF, 5.0]]])
    ds = torch.tensor([[[INF, 3.0, INF]]])
    m = disocclusion_mask(dt, torch.zeros(2, 1, 3), ds)
    assert m[0, 0].tolist() == [False, True, False]


@settings(max_examples=25, deadline=None)
@given(st.integers(1, 6), st.integers(1, 6), st.integers(0, 2 ** 31 - 1),
       st.sampled_from([0.0, 1.0, 1e9, float("nan"), float("inf")]))
def test_motion_ops_finite(h, w, seed, special):
    g = torch.Generator().manual_seed(seed)
    mvs = [(torch.rand(2, h, w, generator=g) - 0.5) * 8 for _ in range(3)]
    mvs[1][0, 0, 0] = special
    out = chain_mv(mvs)
    assert out.shape == (2, h, w) and torch.isfinite(out).all()
    d = torch.rand(1, h, w, generator=g) * 10
    d[0, 0, 0] = special
    m = disocclusion_mask(d, mvs[1], d)
    assert m.shape == (1, h, w)
