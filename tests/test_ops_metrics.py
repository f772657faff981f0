"""fgcli.ops.metrics: psnr, ssim, flip_ldr, flip_hdr, masked_mean."""
import math

import numpy as np
import pytest
import torch

from fgcli.ops import flip_hdr, flip_ldr, masked_mean, psnr, ssim, ssim_map


def img(h=16, w=20, seed=0, scale=1.0):
    g = torch.Generator().manual_seed(seed)
    return torch.rand(3, h, w, generator=g) * scale


def test_psnr_known_values():
    a = torch.zeros(3, 4, 4)
    b = torch.full((3, 4, 4), 0.1)
    assert math.isclose(psnr(a, b, transform="none"), 20.0, rel_tol=1e-5)
    assert psnr(a, a) == 100.0
    # torch and numpy inputs agree; srgb is the default transform
    x, y = img(), img(seed=1)
    assert math.isclose(psnr(x, y), psnr(x.numpy(), y.numpy()), rel_tol=1e-6)
    assert psnr(x, y) != psnr(x, y, transform="none")
    assert math.isfinite(psnr(x * 100, y * 100, transform="mulaw", peak=100.0))


def test_psnr_mask():
    a = torch.zeros(3, 4, 4)
    b = torch.zeros(3, 4, 4)
    b[:, 0, 0] = 0.5
    m = torch.zeros(4, 4, dtype=torch.bool)
    m[0, 0] = True
    assert math.isclose(psnr(a, b, mask=m, transform="none"), 10 * math.log10(4), rel_tol=1e-5)
    assert psnr(a, b, mask=~m, transform="none") == 100.0
    assert math.isnan(psnr(a, b, mask=torch.zeros(1, 4, 4, dtype=torch.bool)))
    with pytest.raises(ValueError, match="mask"):
        psnr(a, b, mask=torch.zeros(3, 3, dtype=torch.bool))


def test_ssim_identity_and_order():
    x = img()
    assert math.isclose(ssim(x, x), 1.0, rel_tol=1e-5)
    noisy = (x + 0.05 * img(seed=3)).clamp(0, 1)
    noisier = (x + 0.3 * img(seed=3)).clamp(0, 1)
    s1, s2 = ssim(x, noisy), ssim(x, noisier)
    assert 1.0 > s1 > s2 > -1.0
    m = ssim_map(x, noisy)
    assert m.shape == (16, 20) and m.dtype == np.float32
    mask = np.zeros((16, 20), bool)
    mask[:8] = True
    assert math.isclose(ssim(x, noisy, mask=mask), float(m[:8].mean()), rel_tol=1e-5)


@pytest.mark.parametrize("h,w", [(1, 1), (1, 7), (5, 1), (3, 2)])
def test_tiny_images(h, w):
    x, y = img(h, w), img(h, w, seed=5)
    for v in (psnr(x, y), ssim(x, y), flip_ldr(x, y), flip_hdr(x * 4, y * 4)):
        assert math.isfinite(v)
    assert math.isclose(ssim(x, x), 1.0, rel_tol=1e-5)


def test_hard_values():
    x = img()
    y = x.clone()
    y[0, 0, 0] = float("nan")
    y[1, 1, 1] = float("inf")
    y[2, 2, 2] = 65504.0
    y[0, 3, 3] = -5.0
    for v in (psnr(x, y), ssim(x, y), flip_ldr(x, y), flip_hdr(x, y)):
        assert math.isfinite(v)


def test_flip_ldr():
    x = img(24, 24)
    assert flip_ldr(x, x) == 0.0
    y = (x + 0.2).clamp(0, 1)
    val, emap = flip_ldr(x, y, return_map=True)
    assert 0.0 < val < 1.0 and emap.shape == (24, 24)
    assert math.isclose(val, float(emap.mean()), rel_tol=1e-5)
    mask = np.zeros((24, 24), bool)
    mask[5:10, 5:10] = True
    assert math.isclose(flip_ldr(x, y, mask=mask), float(emap[mask].mean()), rel_tol=1e-5)
    assert math.isnan(flip_ldr(x, y, mask=np.zeros((24, 24), bool)))


def test_flip_hdr_and_degenerate_references():
    x = img(24, 24, scale=20.0)
    assert flip_hdr(x, x) == 0.0
    v = flip_hdr(x, x * 1.5)
    assert 0.0 < v < 1.0
    black = torch.zeros(3, 24, 24)
    # FLIP itself would call exit() on a black reference; we must survive it
    assert math.isfinite(flip_hdr(black, x))
    assert flip_hdr(black, black) == 0.0
    mostly_black = torch.zeros(3, 24, 24)
    mostly_black[:, :3] = 1000.0  # near-black median: huge automatic exposure range
    assert math.isfinite(flip_hdr(mostly_black, mostly_black * 0.5, max_stops=4))


def test_masked_mean_and_bad_input():
    v = np.arange(12.0).reshape(3, 4)
    assert masked_mean(v) == 5.5
    m = np.zeros((3, 4), bool)
    m[0] = True
    assert masked_mean(v, m) == 1.5
    assert math.isnan(masked_mean(v, np.zeros((3, 4), bool)))
    with pytest.raises(ValueError, match="3, H, W"):
        psnr(torch.zeros(4, 4), torch.zeros(4, 4))
    with pytest.raises(ValueError, match="mismatch"):
        ssim(torch.zeros(3, 4, 4), torch.zeros(3, 4, 5))
