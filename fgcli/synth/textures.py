"""Procedural textures on 2D surface coordinates (object units), band-limited by a soft edge.

All functions take torch tensors u, v of shape (N,) and return albedo components (r, g, b),
each (N,). Integer hashing keeps them deterministic across machines and thread counts.
"""
from __future__ import annotations

import math

import torch

from fgcli.synth.scene import Texture


def _soft_square(u: torch.Tensor, w) -> torch.Tensor:
    """Square wave (+1 on even cells, -1 on odd) with edges of width ~2w (cell units; a float
    or a per-point tensor). Wide edges fade the wave toward 0, as a pre-filtered texture."""
    s = torch.sin(u * math.pi)
    if not isinstance(w, torch.Tensor) and w <= 0:
        return torch.sign(s)
    return torch.clamp(s / (math.pi * w), -1.0, 1.0)


def _hash(ix: torch.Tensor, iy: torch.Tensor, seed: int) -> torch.Tensor:
    """Integer lattice hash -> float in [0, 1). ix, iy: int64."""
    m = 0xFFFFFFFF
    n = (ix * 374761393 + iy * 668265263 + (seed * 1442695041 & m)) & m
    n = ((n ^ (n >> 13)) * 1274126177) & m
    n = n ^ (n >> 16)
    return (n & 0xFFFFFF).to(torch.float32) * (1.0 / 16777216.0)


def _value_noise(u: torch.Tensor, v: torch.Tensor, seed: int) -> torch.Tensor:
    fu, fv = torch.floor(u), torch.floor(v)
    iu, iv = fu.to(torch.int64), fv.to(torch.int64)
    a, b = u - fu, v - fv
    a = a * a * a * (a * (a * 6 - 15) + 10)
    b = b * b * b * (b * (b * 6 - 15) + 10)
    h00, h10 = _hash(iu, iv, seed), _hash(iu + 1, iv, seed)
    h01, h11 = _hash(iu, iv + 1, seed), _hash(iu + 1, iv + 1, seed)
    top = h00 + (h10 - h00) * a
    bot = h01 + (h11 - h01) * a
    return top + (bot - top) * b


def _mix(tex: Texture, w: torch.Tensor):
    """colors[1] where w = 0, colors[0] where w = 1."""
    c0, c1 = tex.colors[0], tex.colors[1]
    return tuple(float(c1[i]) + float(c0[i] - c1[i]) * w for i in range(3))


def evaluate(tex: Texture, u: torch.Tensor, v: torch.Tensor, seconds: float = 0.0,
             scroll: bool = False, footprint: torch.Tensor | None = None):
    """Albedo (r, g, b) of `tex` at surface coordinates (u, v).

    footprint: size of the pixel on the surface (object units, per point). Detail finer
    than it fades to its average, as a mip-mapped texture does: the image stays
    band-limited at every distance, so it resamples (warps) without aliasing.
    """
    if scroll and (tex.scroll[0] or tex.scroll[1]):
        u = u + float(tex.scroll[0] * seconds)
        v = v + float(tex.scroll[1] * seconds)
    k = tex.kind
    if k == "solid":
        c = tex.colors[0]
        return tuple(torch.full_like(u, float(c[i])) for i in range(3))
    s = 1.0 / tex.scale
    fp = footprint
    if k in ("checker", "stripes"):
        w = tex.softness if fp is None else torch.clamp(fp * s, min=tex.softness)
        if k == "checker":
            w = 0.5 + 0.5 * _soft_square(u * s, w) * _soft_square(v * s, w)
        else:
            a = math.radians(tex.angle)
            w = 0.5 + 0.5 * _soft_square((u * math.cos(a) + v * math.sin(a)) * s, w)
        return _mix(tex, w)
    if k == "noise":
        total = torch.zeros_like(u)
        amp, norm, f = 1.0, 0.0, s
        for o in range(tex.octaves):
            nz = _value_noise(u * f, v * f, tex.seed + 7919 * o)
            if fp is not None:  # octaves finer than the footprint fade to their mean
                nz = 0.5 + (nz - 0.5) * torch.clamp(1.5 - 2.0 * f * fp, 0.0, 1.0)
            total = total + amp * nz
            norm += amp
            amp *= 0.5
            f *= 2.0
        return _mix(tex, total * (1.0 / norm))
    if k == "bricks":
        bh, bw = tex.scale, 2.0 * tex.scale
        row = torch.floor(v * (1.0 / bh))
        uu = u * (1.0 / bw) + 0.5 * torch.remainder(row, 2.0)
        col = torch.floor(uu)
        fu = (uu - col) * bw
        fv = v - row * bh
        d = torch.minimum(torch.minimum(fu, bw - fu), torch.minimum(fv, bh - fv))
        m = 0.5 * tex.mortar * bh
        e = max(tex.softness * bh * 0.5, 1e-6)
        if fp is not None:
            e = torch.clamp(0.5 * fp, min=e)
        brick = torch.clamp((d - m) / (2 * e) + 0.5, 0.0, 1.0)
        var = 1.0 + tex.variation * (2.0 * _hash(col.to(torch.int64), row.to(torch.int64),
                                                 tex.seed) - 1.0)
        c0, c1 = tex.colors[0], tex.colors[1]
        return tuple(float(c1[i]) + (float(c0[i]) * var - float(c1[i])) * brick for i in range(3))
    raise ValueError(k)  # pragma: no cover - validated at load time
