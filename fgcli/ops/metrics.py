"""Image-quality metrics for `fgen eval` (docs/design.md section 4).

Inputs: torch tensors or numpy arrays, (3, H, W) *linear* scene-referred colour (the frame
model's ``color``); PSNR, SSIM and LDR-FLIP first map it to display-referred colour
(``transform``: 'srgb' = sRGB OETF of clip(x, 0, 1), the default; 'mulaw'; or 'none' for
inputs that are already display-referred in [0, 1]). HDR-FLIP works on the linear colour.
Masks: (H, W) or (1, H, W) bool (torch or numpy); metrics are then averaged over the
masked pixels only. An empty mask gives ``nan`` (no pixels to score, not an error).
Non-finite inputs are cleaned (NaN -> 0, +inf -> the clip maximum). Results are Python
floats.
"""
from __future__ import annotations

import math

import numpy as np

from fgcli.ops.color import to_display

PSNR_MAX_DB = 100.0  # identical images: PSNR is capped here instead of +inf (JSON-safe)
SSIM_K1, SSIM_K2 = 0.01, 0.03
SSIM_SIGMA, SSIM_WIN = 1.5, 11
HALF_MAX = 65504.0


def _np(x, name) -> np.ndarray:
    if hasattr(x, "detach"):
        x = x.detach().cpu().numpy()
    a = np.asarray(x)
    if a.dtype == bool:
        return a
    return a.astype(np.float32, copy=False)


def _check_pair(a, b):
    a = _np(a, "a")
    b = _np(b, "b")
    if a.ndim != 3 or a.shape[0] != 3:
        raise ValueError(f"expected (3, H, W) colour, got shape {a.shape}")
    if b.shape != a.shape:
        raise ValueError(f"shape mismatch: {a.shape} vs {b.shape}")
    if a.shape[1] == 0 or a.shape[2] == 0:
        raise ValueError(f"empty image, shape {a.shape}")
    return a, b


def _mask(mask, shape_hw):
    if mask is None:
        return None
    m = _np(mask, "mask")
    if m.ndim == 3 and m.shape[0] == 1:
        m = m[0]
    if m.shape != tuple(shape_hw):
        raise ValueError(f"mask: expected shape {tuple(shape_hw)} or (1, H, W), got {m.shape}")
    return m.astype(bool, copy=False)


def masked_mean(values, mask=None) -> float:
    """Mean of an (H, W) map (or (C, H, W): mean over channels too) over mask pixels; nan
    for an empty mask."""
    v = _np(values, "values").astype(np.float64, copy=False)
    m = _mask(mask, v.shape[-2:])
    if m is None:
        return float(v.mean())
    if not m.any():
        return float("nan")
    if v.ndim == 3:
        return float(v[:, m].mean())
    return float(v[m].mean())


def psnr(a, b, mask=None, transform: str = "srgb", mu: float = 5000.0,
         peak: float = 1.0) -> float:
    """PSNR in dB on display-referred colour (peak signal 1): ``10 log10(1 / MSE)``, MSE
    over all channels of the (masked) pixels. Identical images give PSNR_MAX_DB (100 dB).
    a, b: (3, H, W) linear colour; transform: 'srgb' | 'mulaw' | 'none' (mu, peak: mulaw)."""
    a, b = _check_pair(a, b)
    m = _mask(mask, a.shape[1:])
    da = to_display(a, transform, mu, peak)
    db = to_display(b, transform, mu, peak)
    se = np.square(da - db, dtype=np.float32)
    mse = masked_mean(se, m)
    if math.isnan(mse):
        return mse
    if mse <= 10.0 ** (-PSNR_MAX_DB / 10.0):
        return PSNR_MAX_DB
    return float(10.0 * math.log10(1.0 / mse))


def ssim_map(a, b, transform: str = "srgb", mu: float = 5000.0, peak: float = 1.0):
    """Per-pixel SSIM (H, W), float32: Wang et al. 2004 with an 11x11 Gaussian window
    (sigma 1.5), K1 = 0.01, K2 = 0.03, dynamic range 1, on display-referred colour,
    computed per channel and averaged over the 3 channels. Borders are handled by
    reflecting the image (so every pixel, also of tiny images, gets a value; tools that
    crop the 5-pixel border differ slightly there)."""
    import cv2

    a, b = _check_pair(a, b)
    da = to_display(a, transform, mu, peak).astype(np.float32)
    db = to_display(b, transform, mu, peak).astype(np.float32)
    c1 = (SSIM_K1 * 1.0) ** 2
    c2 = (SSIM_K2 * 1.0) ** 2
    h, w = a.shape[1:]
    border = cv2.BORDER_REFLECT if min(h, w) > 1 else cv2.BORDER_REPLICATE

    def blur(x):
        return cv2.GaussianBlur(x, (SSIM_WIN, SSIM_WIN), SSIM_SIGMA, borderType=border)

    acc = np.zeros((h, w), np.float32)
    for c in range(3):
        x, y = np.ascontiguousarray(da[c]), np.ascontiguousarray(db[c])
        mx, my = blur(x), blur(y)
        sxx = blur(x * x) - mx * mx
        syy = blur(y * y) - my * my
        sxy = blur(x * y) - mx * my
        num = (2 * mx * my + c1) * (2 * sxy + c2)
        den = (mx * mx + my * my + c1) * (sxx + syy + c2)
        acc += num / den
    return acc / 3.0


def ssim(a, b, mask=None, transform: str = "srgb", mu: float = 5000.0,
         peak: float = 1.0) -> float:
    """Mean SSIM (see ssim_map) over all pixels or the masked ones; 1.0 for identical
    images, nan for an empty mask."""
    a, b = _check_pair(a, b)
    m = _mask(mask, a.shape[1:])
    if m is not None and not m.any():
        return float("nan")
    return masked_mean(ssim_map(a, b, transform, mu, peak), m)


def _hwc(x):
    return np.ascontiguousarray(np.transpose(x, (1, 2, 0)), dtype=np.float32)


def _flip_params(ppd):
    p = {}
    if ppd is not None:
        if not (ppd > 0 and math.isfinite(ppd)):
            raise ValueError(f"ppd: must be positive and finite, got {ppd!r}")
        p["ppd"] = float(ppd)
    return p


def flip_ldr(ref, test, mask=None, transform: str = "srgb", return_map: bool = False,
             ppd: float | None = None, mu: float = 5000.0, peak: float = 1.0):
    """LDR-FLIP (NVIDIA ``flip_evaluator``) on display-referred colour.

    ref, test: (3, H, W) linear colour, mapped with ``transform`` ('srgb' default) and
    handed to FLIP as sRGB-encoded LDR images. ppd: pixels per degree (FLIP default 67).
    Returns the mean error over all or the masked pixels (nan for an empty mask), or
    ``(mean, error_map)`` with the (H, W) float32 map when return_map.
    """
    import flip_evaluator as flip

    a, b = _check_pair(ref, test)
    m = _mask(mask, a.shape[1:])
    ra = _hwc(to_display(a, transform, mu, peak))
    rb = _hwc(to_display(b, transform, mu, peak))
    emap, _mean, _p = flip.evaluate(ra, rb, "LDR", inputsRGB=True, applyMagma=False,
                                    computeMeanError=False, parameters=_flip_params(ppd))
    emap = np.asarray(emap, dtype=np.float32).reshape(a.shape[1:])
    val = masked_mean(emap, m)
    return (val, emap) if return_map else val


def _aces_x(t: float = 0.85) -> float:
    # FLIP's exposure anchors for its ACES curve (Andersson et al. 2021, HDR-FLIP)
    k0, k1, k2 = 0.6 * 0.6 * 2.51, 0.6 * 0.03, 0.0
    k3, k4, k5 = 0.6 * 0.6 * 2.43, 0.6 * 0.59, 0.14
    c0 = (k1 - k4 * t) / (k0 - k3 * t)
    c1 = (k2 - k5 * t) / (k0 - k3 * t)
    return -0.5 * c0 + math.sqrt((0.5 * c0) ** 2 - c1)


def flip_hdr(ref, test, mask=None, return_map: bool = False, ppd: float | None = None,
             max_stops: float = 12.0):
    """HDR-FLIP (NVIDIA ``flip_evaluator``) on linear colour.

    ref, test: (3, H, W) linear colour; NaN -> 0 and values clipped to [0, 65504].
    The exposure range is FLIP's automatic one (from the reference's max and median
    luminance), with two guards the library lacks: a black reference (max luminance
    <= 1e-8, on which FLIP would abort the process) is evaluated at exposure 0, and the
    range is capped at ``max_stops`` stops (a near-black median makes FLIP evaluate 20+
    exposures, each a full LDR-FLIP). Returns the mean (or masked mean; nan for an empty
    mask), or ``(mean, error_map)`` when return_map.
    """
    import flip_evaluator as flip

    a, b = _check_pair(ref, test)
    m = _mask(mask, a.shape[1:])
    a = np.clip(np.nan_to_num(a, nan=0.0, posinf=HALF_MAX, neginf=0.0), 0.0, HALF_MAX)
    b = np.clip(np.nan_to_num(b, nan=0.0, posinf=HALF_MAX, neginf=0.0), 0.0, HALF_MAX)
    params = _flip_params(ppd)
    y = (0.2126 * a[0] + 0.7152 * a[1] + 0.0722 * a[2]).astype(np.float64)
    y_hi = float(y.max())
    if y_hi <= 1e-8:
        params.update(startExposure=0.0, stopExposure=0.0)
    else:
        x = _aces_x()
        start = math.log2(x / y_hi)
        y_lo = float(np.median(y))
        stop = math.log2(x / y_lo) if y_lo > 0 else math.inf
        if stop - start > max_stops:
            params.update(startExposure=start, stopExposure=start + float(max_stops))
    emap, _mean, _p = flip.evaluate(_hwc(a), _hwc(b), "HDR", applyMagma=False,
                                    computeMeanError=False, parameters=params)
    emap = np.asarray(emap, dtype=np.float32).reshape(a.shape[1:])
    val = masked_mean(emap, m)
    return (val, emap) if return_map else val
