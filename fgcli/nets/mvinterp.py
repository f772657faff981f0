"""The mv-interp network (seed 000, "motion-vector-guided frame interpolation"):
a motion context encoder fed with both frames backward-warped by their guiding flows and the
flows, an image pyramid encoder, and four IFRNet decoders that add the motion encoder's
refined guiding flows to their own flows (``f_bar = m + f``) at every level; the first
decoder also sees the time T. The last decoder outputs the two flows, a merge mask M and a
residual R, and the frame is Eq. 5: ``I_t = M·W(I0, f0) + (1-M)·W(I1, f1) + R``.

fgen choices, stated:
- Widths (an option): the default (16, 24, 32, 48) is 1/2 of IFRNet's (32, 48, 72, 96) so
  that the network trains on 2 CPU cores in about an hour (docs/training.md) and runs a
  1080p frame in well under the 2 s target through onnxruntime.
- Colour: mu-law (mu 8, clip [0, 100]) inside the network. The blend of Eq. 5 is done on
  the linear colours and R is added in the tone-mapped space, so where R = 0 an HDR value
  above the clip passes through unchanged.
- The flows the decoders refine are residuals over the guiding flows (``f = 0`` at the
  start, every output head zero-initialised): an untrained network is exactly the
  guiding-flow warp with an even blend, and training only has to improve on it.
- The motion encoder's refined guiding flows are ``m^k = down(M)/2^k + head(feature)``.
- Guiding flows from the Mob-FGSR motion chain, and two cue channels (depth ratio of the
  guided samples, hole mask) into the motion encoder: see fgcli.ops.mvinterp.
Input height and width must be multiples of 16 (the stage pads by replication and crops).
"""
from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from fgcli.nets.blocks import ResBlock, conv, conv_transpose_as_conv, resize_flow, warp
from fgcli.ops.mvinterp import tonemap, untonemap

DEFAULT_WIDTHS = (16, 24, 32, 48)
MULTIPLE = 16


class Encoder(nn.Module):
    """Four levels, each a stride-2 and a stride-1 3x3 conv (+ PReLU)."""

    def __init__(self, cin: int, widths):
        super().__init__()
        levels, c = [], cin
        for w in widths:
            levels.append(nn.Sequential(conv(c, w, 3, 2), conv(w, w, 3, 1)))
            c = w
        self.levels = nn.ModuleList(levels)

    def forward(self, x):
        out = []
        for lv in self.levels:
            x = lv(x)
            out.append(x)
        return out


class Decoder(nn.Module):
    """IFRNet decoder block: conv, residual block, 4x4 transposed conv up to the next level."""

    def __init__(self, cin: int, c: int, cout: int, side: int):
        super().__init__()
        self.body = nn.Sequential(conv(cin, c), ResBlock(c, side))
        self.up = nn.ConvTranspose2d(c, cout, 4, 2, 1)

    def forward(self, x):
        x = self.body(x)
        if torch.onnx.is_in_onnx_export():  # the faster ONNX form of the same layer
            return conv_transpose_as_conv(self.up, x)
        return self.up(x)


def _zero(m: nn.Module) -> nn.Module:
    for p in m.parameters():
        nn.init.zeros_(p)
    return m


class MVInterpNet(nn.Module):
    def __init__(self, widths=DEFAULT_WIDTHS):
        super().__init__()
        w = tuple(int(x) for x in widths)
        if len(w) != 4:
            raise ValueError("widths: four numbers")
        self.widths = w
        self.img_enc = Encoder(3, w)
        self.mot_enc = Encoder(3 + 3 + 4 + 2, w)
        self.mot_heads = nn.ModuleList(_zero(nn.Conv2d(c, 4, 3, 1, 1)) for c in w)
        sides = [max(4, c // 3) for c in w]
        # level 4: warped X0, X1, motion feature, m (4), T
        self.dec4 = Decoder(3 * w[3] + 5, w[3], 4 + w[2], sides[3])
        self.dec3 = Decoder(4 * w[2] + 4, w[2], 4 + w[1], sides[2])
        self.dec2 = Decoder(4 * w[1] + 4, w[1], 4 + w[0], sides[1])
        self.dec1 = Decoder(4 * w[0] + 4, w[0], 4 + 1 + 3, sides[0])
        for d in (self.dec4, self.dec3, self.dec2, self.dec1):
            # flow (and mask/residual) outputs start at zero; features keep their init
            with torch.no_grad():
                d.up.weight[:, :4].zero_()
                d.up.bias[:4].zero_()
        with torch.no_grad():
            self.dec1.up.weight.zero_()
            self.dec1.up.bias.zero_()

    def forward(self, c0, c1, g0, g1, cue, t):
        """c0, c1: (B, 3, H, W) linear colour; g0, g1: (B, 2, H, W) guiding flows (pixels);
        cue: (B, 2, H, W) depth-ratio and hole channels (fgcli.ops.mvinterp.guide_cues);
        t: (B, 1, 1, 1) time. Returns colour (B, 3, H, W) and the final flows f0, f1 and
        mask M (B, 1, H, W)."""
        x0, x1 = tonemap(c0), tonemap(c1)
        w0, w1 = warp(x0, g0), warp(x1, g1)
        f0, f1, M, R = self.core(x0, x1, w0, w1, g0, g1, cue, t)
        return synthesize(c0, c1, f0, f1, M, R), f0, f1, M

    def core(self, x0, x1, w0, w1, g0, g1, cue, t):
        """The network proper, between the full-resolution warps (which the ONNX export
        leaves to torch: onnxruntime's GridSample costs ~40 % of a 1080p frame):
        x0, x1 tone-mapped frames, w0, w1 the same warped by the guiding flows.
        Returns f0, f1 (B, 2, H, W), M (B, 1, H, W), R (B, 3, H, W)."""
        feats_i0 = self.img_enc(x0)
        feats_i1 = self.img_enc(x1)
        feats_m = self.mot_enc(torch.cat([w0, w1, g0, g1, cue], 1))
        g = torch.cat([g0, g1], 1)
        ms = []
        for k, (fm, head) in enumerate(zip(feats_m, self.mot_heads)):
            s = 0.5 ** (k + 1)
            gk = F.interpolate(g, size=fm.shape[-2:], mode="bilinear", align_corners=False) * s
            ms.append(gk + head(fm))
        # level 4 (index 3)
        m = ms[3]
        X0, X1 = feats_i0[3], feats_i1[3]
        T = t.expand(-1, 1, X0.shape[2], X0.shape[3])
        out = self.dec4(torch.cat([warp(X0, m[:, :2]), warp(X1, m[:, 2:]), feats_m[3], m, T], 1))
        f, Xt = out[:, :4], out[:, 4:]
        for lvl, dec in ((2, self.dec3), (1, self.dec2), (0, self.dec1)):
            fb = ms[lvl] + f
            X0, X1 = feats_i0[lvl], feats_i1[lvl]
            out = dec(torch.cat([warp(X0, fb[:, :2]), warp(X1, fb[:, 2:]), Xt, feats_m[lvl], fb],
                                1))
            f = resize_flow(f, 2.0) + out[:, :4]
            Xt = out[:, 4:]
        flows = g + f
        return flows[:, :2], flows[:, 2:], torch.sigmoid(Xt[:, :1]), Xt[:, 1:4]


class MVInterpCore(nn.Module):
    """MVInterpNet.core as a module (what fgcli.nets.export writes to ONNX)."""

    def __init__(self, net: MVInterpNet):
        super().__init__()
        self.net = net

    def forward(self, x0, x1, w0, w1, g0, g1, cue, t):
        return self.net.core(x0, x1, w0, w1, g0, g1, cue, t)


def synthesize(c0, c1, f0, f1, M, R):
    """Eq. 5 on linear colour, the residual added in tone-mapped space; where R == 0 the
    exact linear blend (HDR above the tone-map clip passes through)."""
    lin = M * warp(c0, f0) + (1.0 - M) * warp(c1, f1)
    color = untonemap(tonemap(lin) + R)
    return torch.where(R == 0, lin, color)
