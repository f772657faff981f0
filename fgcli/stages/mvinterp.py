"""mv-interp stages (pipelines/mv-interp.toml): guiding flows from frame 1's splatted
vectors and the trained network (fgcli.nets), with the network-off warp of the ablation."""
from __future__ import annotations

from fgcli.stages.base import Option, Stage, register


@register
class Guide(Stage):
    name = "guide"
    uses_kernels = True
    help = ("mv-interp guiding flows (seed 000 §3.1, splat 'following Mob-FGSR'): the "
            "Mob-FGSR motion chain (dilate, quadratic splat, gap fill, holes from frame 0's "
            "vectors; linear and frame 1's vectors without them) and the cue channels "
            "(depth ratio of the guided samples, holes; fgen extension).")
    inputs = ("depth1", "mv1", "alpha")
    optional_inputs = ("mv0", "depth0")
    outputs = ("guide0", "guide1", "guide_cue")
    options = (
        Option("undilated_holes", "bool", True, "holes of the dilated splat take frame 1's "
               "own (undilated) splat where it reaches them, before the hole fallback: the "
               "dilation leaves a static surface beside a moving one empty at time t although "
               "frame 1 sees it there (fgen extension; figures in docs/results.md)"),
    )

    def needed(self, ctx, facts):
        if not facts["any_motion"]:
            return False, "no motion: zero guiding flows"
        return True, ""

    def skip(self, ctx):
        import torch

        d = ctx["depth1"]
        z = torch.zeros(2, *d.shape[-2:], dtype=torch.float32, device=d.device)
        return {"guide0": z, "guide1": z.clone(), "guide_cue": self._cue(ctx, z, z, None)}

    @staticmethod
    def _cue(ctx, g0, g1, holes):
        import torch

        from fgcli.ops.mvinterp import guide_cues

        d1 = ctx["depth1"]
        d0 = ctx.get("depth0") if ctx.get("depth0") is not None else d1
        if holes is None:
            holes = torch.zeros(1, *d1.shape[-2:], dtype=torch.bool, device=d1.device)
        return guide_cues(d0, d1, g0, g1, holes)

    def run(self, ctx):
        from fgcli.kernels import op

        mv0 = ctx.get("mv0")
        g0, g1, holes = op("guiding_flows", ctx)(ctx["depth1"], ctx["mv1"], ctx["alpha"], mv0,
                                                 ctx.get("depth0") if mv0 is not None else None,
                                                 self.undilated_holes)
        return {"guide0": g0, "guide1": g1, "guide_cue": self._cue(ctx, g0, g1, holes)}


def _depth_and_mv(ctx, f0, f1, alpha):
    """Depth of the generated frame (the nearer of the two samples along the final flows)
    and its vectors toward the previous output time (f0 scaled to that time)."""
    import torch

    from fgcli.ops import sample_nearest, sanitize_depth

    d0, _ = sample_nearest(sanitize_depth(ctx["depth0"]), f0)
    d1, _ = sample_nearest(sanitize_depth(ctx["depth1"]), f1)
    depth = torch.minimum(d0, d1)
    prev = float(ctx.get("prev_time") or 0.0)
    mv = f0 * ((alpha - prev) / alpha) if (alpha > 0 and prev > 0) else f0
    return depth, mv


def _cue_depth_limit(depth_rel: float) -> float:
    """The depth cue (channel 0 of fgcli.ops.mvinterp.guide_cues: the clamped log(d0 / d1)
    / CUE_LOG_RANGE) of two depths depth_rel apart."""
    import math

    from fgcli.ops.mvinterp import CUE_LOG_RANGE

    return math.log1p(depth_rel) / CUE_LOG_RANGE


def static_pixels(g0, g1, cue, depth_rel: float = 0.02):
    """(1, H, W) bool: both guiding flows below 1e-3 px in each component, no hole, and the
    guided samples' depths within depth_rel of each other (cue channel 1 is the hole mask)."""
    still = (g0.abs().amax(0, keepdim=True) < 1e-3) & (g1.abs().amax(0, keepdim=True) < 1e-3)
    same = cue[0:1].abs() <= _cue_depth_limit(depth_rel)
    return still & same & (cue[1:2] < 0.5)


def occluder_holes(cue, depth_rel: float = 0.02):
    """(1, H, W) bool: guide holes (no frame-1 surface splats there) whose frame-1 guided
    sample is nearer than frame 0's by more than depth_rel: frame 1 shows an occluder."""
    return (cue[1:2] > 0.5) & (cue[0:1] > _cue_depth_limit(depth_rel))


TRAINED_TAUS = (0.25, 0.75)  # the shipped weights saw tau in {0.25, 0.5, 0.75}


def trained_weight(alpha: float) -> float:
    """Weight of the network's frame at time alpha: 1 on the trained range [0.25, 0.75],
    falling linearly to 0 at alpha 0 and 1, where the guided warp takes over (a network
    asked for times it never saw does not converge to the rendered frames)."""
    return max(0.0, min(1.0, min(alpha, 1.0 - alpha) / TRAINED_TAUS[0]))


@register
class MVInterpNet(Stage):
    name = "mvinterp_net"
    help = ("mv-interp network (seed 000): motion context encoder on both frames warped by "
            "the guiding flows, image pyramid encoder, four IFRNet decoders with f_bar = m + "
            "f, Eq. 5 synthesis. Shipped weights (fgcli/nets/weights), onnxruntime on CPU, "
            "torch on CUDA. Trained at alpha 0.25-0.75: outside it the frame fades linearly "
            "to the guided warp (fgen rule).")
    inputs = ("color0", "color1", "depth0", "depth1", "alpha")
    optional_inputs = ("guide0", "guide1", "guide_cue", "prev_time")
    outputs = ("color", "depth", "mv")
    options = (
        Option("network", "bool", True, "off: the ablation without the network, both frames "
               "backward-warped by the guiding flows and blended by time"),
        Option("backend", "choice", "auto", "auto = onnxruntime on CPU, torch on CUDA",
               choices=("auto", "onnx", "torch")),
        Option("weights", "str", "mv-interp", "weights name in fgcli/nets/weights"),
        Option("static_crossfade", "bool", True, "where both guiding flows are zero, the "
               "pixel is no hole, the two frames' depths agree (2 %) and their colours nearly "
               "agree (static_tol), cross-fade the frames instead of the network's frame "
               "(fgen extension; needs the guide stage; tolerance chosen on held-out random "
               "scenes, figures in docs/results.md)"),
        Option("static_tol", "float", 0.03, "static_crossfade only where the two frames' "
               "tone-mapped colours differ by at most this (max over channels; mu-law units, "
               "1 = the tone map's range): a near-constant pixel is exact as a cross-fade, a "
               "changing one (a shadow edge sweeping) is the network's; 1e9 = every static "
               "pixel", range=(0.0, 1e9)),
        Option("hole_mask_min", "float", 0.0, "guide holes (no frame-1 surface splats to "
               "the pixel) whose frame-1 guided sample is nearer than frame 0's (2 %): "
               "frame 1 shows an occluder there, so the merge mask M (weight of frame 0) is "
               "raised to at least this (fgen extension; 0 = the network's M)",
               range=(0.0, 1.0)),
    )

    def needed(self, ctx, facts):
        import torch

        a = float(ctx["alpha"])
        if a <= 0.0 or a >= 1.0:
            return False, "alpha at a rendered frame: the guided warp is that frame"
        if not facts["any_motion"] and torch.equal(ctx["color0"], ctx["color1"]):
            return False, "no motion and identical frames: the frame itself"
        return True, ""

    def skip(self, ctx):
        import torch

        from fgcli.ops import sanitize_values

        if torch.equal(ctx["color0"], ctx["color1"]) and float(ctx["alpha"]) > 0.0:
            z = torch.zeros(2, *ctx["color1"].shape[-2:], dtype=torch.float32,
                            device=ctx["color1"].device)
            depth, mv = _depth_and_mv(ctx, z, z, float(ctx["alpha"]))
            return {"color": sanitize_values(ctx["color1"]), "depth": depth, "mv": mv}
        return self._warp_only(ctx)

    @staticmethod
    def _inputs(ctx):
        """Sanitised colours, guiding flows and cue channels (zeros when the guide stage is
        off: the plain IFRNet-style ablation)."""
        import torch

        from fgcli.ops import sanitize_mv, sanitize_values

        c0, c1 = sanitize_values(ctx["color0"]), sanitize_values(ctx["color1"])
        if ctx.get("guide0") is None:
            g0 = g1 = torch.zeros(2, *c0.shape[-2:], dtype=torch.float32, device=c0.device)
            return c0, c1, g0, g1, torch.zeros_like(g0)
        return c0, c1, sanitize_mv(ctx["guide0"]), sanitize_mv(ctx["guide1"]), ctx["guide_cue"]

    def _warp_only(self, ctx, inputs=None):
        from fgcli.ops.mvinterp import guide_warp

        a = float(ctx["alpha"])
        c0, c1, g0, g1, _ = inputs or self._inputs(ctx)
        depth, mv = _depth_and_mv(ctx, g0, g1, a)
        return {"color": guide_warp(c0, c1, g0, g1, a), "depth": depth, "mv": mv}

    def run(self, ctx):
        import torch
        import torch.nn.functional as F

        from fgcli.nets.mvinterp import MULTIPLE
        from fgcli.nets.runtime import run_mvinterp

        a = float(ctx["alpha"])
        inputs = self._inputs(ctx)
        c0, c1, g0, g1, cue = inputs
        if not self.network:
            return self._warp_only(ctx, inputs)
        H, W = c0.shape[-2:]
        ph, pw = (-H) % MULTIPLE, (-W) % MULTIPLE
        x = [v[None] for v in (c0, c1, g0, g1, cue)]
        if ph or pw:
            # replicate padding (reflect needs the size to exceed the pad: 1x1 inputs)
            x = [F.pad(v, (0, pw, 0, ph), mode="replicate") for v in x]
        color, f0, f1, mask = run_mvinterp(*x, a, backend=self.backend, name=self.weights)
        color, f0, f1, mask = (v[0, :, :H, :W] for v in (color, f0, f1, mask))
        if self.hole_mask_min > 0.0 and ctx.get("guide0") is not None:
            # M' = max(M, m) where frame 1 shows an occluder at a splat hole; Eq. 5 is
            # linear in M: colour + (M' - M) (W(I0, f0) - W(I1, f1))
            from fgcli.nets.blocks import warp

            dm = torch.where(occluder_holes(cue), (self.hole_mask_min - mask).clamp_min(0.0),
                             torch.zeros_like(mask))
            color = color + dm * (warp(c0[None], f0[None])[0] - warp(c1[None], f1[None])[0])
        color = color.clamp_min(0.0)
        w = trained_weight(a)
        if w < 1.0:
            # outside the times the weights were trained at, fade to the guided warp (which
            # reaches the rendered frames at alpha 0 and 1)
            from fgcli.ops.mvinterp import guide_warp

            color = w * color + (1.0 - w) * guide_warp(c0, c1, g0, g1, a)
            f0 = w * f0 + (1.0 - w) * g0
            f1 = w * f1 + (1.0 - w) * g1
        if self.static_crossfade and ctx.get("guide0") is not None:
            from fgcli.ops.mvinterp import tonemap

            st = static_pixels(g0, g1, cue)
            if self.static_tol < 1e9:
                st &= (tonemap(c1) - tonemap(c0)).abs().amax(0, keepdim=True) <= self.static_tol
            color = torch.where(st, torch.lerp(c0, c1, a), color)
        depth, mv = _depth_and_mv(ctx, f0, f1, a)
        return {"color": color, "depth": depth, "mv": mv}
