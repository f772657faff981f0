"""Baseline stages every eval table carries: repeat, cross-fade blend, mv-warp."""
from __future__ import annotations

from fgcli.stages.base import Option, Stage, register


def _scaled_mv(ctx):
    """Generated-frame MVs under a static-field, linear-motion assumption: frame 1's vectors
    scaled to the time since the previous output frame."""
    from fgcli.ops import sanitize_mv

    a = ctx["alpha"]
    prev = float(ctx.get("prev_time") or 0.0)
    return sanitize_mv(ctx["mv1"]) * (a - prev)


@register
class Repeat(Stage):
    name = "repeat"
    help = ("Baseline: copy the temporally nearest rendered frame (interpolation: frame 0 for "
            "alpha <= 0.5; extrapolation: frame 1).")
    inputs = ("color1", "depth1", "mv1", "alpha", "mode")
    optional_inputs = ("color0", "depth0", "prev_time")
    outputs = ("color", "depth", "mv")

    def run(self, ctx):
        import torch

        a, prev = ctx["alpha"], float(ctx.get("prev_time") or 0.0)
        if ctx["mode"] == "interp" and a <= 0.5:
            color, depth = ctx["color0"], ctx["depth0"]
        else:
            color, depth = ctx["color1"], ctx["depth1"]
        # content jumps to frame 1 at the first output after alpha 0.5 (interp): its vectors
        # then span the whole interval; otherwise the output repeats the previous content
        jump = ctx["mode"] == "interp" and a > 0.5 >= prev
        from fgcli.ops import sanitize_mv, sanitize_values

        mv = sanitize_mv(ctx["mv1"]) if jump else torch.zeros_like(ctx["mv1"])
        return {"color": sanitize_values(color), "depth": depth.clone(), "mv": mv}


@register
class CrossFade(Stage):
    name = "crossfade"
    uses_kernels = True
    help = "Baseline: linear cross-fade (1 - alpha) c0 + alpha c1."
    inputs = ("color0", "color1", "depth0", "depth1", "mv1", "alpha")
    optional_inputs = ("prev_time",)
    outputs = ("color", "depth", "mv")

    def run(self, ctx):
        from fgcli.kernels import op

        a = ctx["alpha"]
        color, depth, mv = op("crossfade", ctx)(
            ctx["color0"], ctx["color1"], ctx["depth0"], ctx["depth1"], ctx["mv1"], a,
            a - float(ctx.get("prev_time") or 0.0))  # mv: as _scaled_mv
        return {"color": color, "depth": depth, "mv": mv}


@register
class MVWarp(Stage):
    name = "mv_warp"
    uses_kernels = True
    help = ("Baseline: backward-warp the nearest rendered frame by its scaled MVs (vector "
            "field treated as static in screen space).")
    inputs = ("color1", "depth1", "mv1", "alpha", "mode")
    optional_inputs = ("color0", "depth0", "prev_time")
    outputs = ("color", "depth", "mv")
    options = (Option("filter", "choice", "bilinear", "resampling filter",
                      choices=("bilinear", "catmull-rom", "nearest")),
               Option("vectors", "choice", "own", "interpolation from frame 0: its own vectors "
                      "(toward t-1, constant velocity) or frame 1's (the pair's interval)",
                      choices=("own", "pair")))

    def needed(self, ctx, facts):
        if not facts["any_motion"] and not facts["history_motion"]:
            return False, "no motion: warp is the identity"
        return True, ""

    def skip(self, ctx):
        out = Repeat().run(ctx)
        return out

    def run(self, ctx):
        from fgcli.kernels import op

        # the reference ops: mv_warp_interp / mv_warp_extrap (colour) and sample_nearest
        # (depth), composed per source frame as fgcli.kernels.reference.mv_warp
        mv_warp = op("mv_warp", ctx)
        a, mv1 = ctx["alpha"], ctx["mv1"]
        if ctx["mode"] == "interp":
            if a <= 0.5 and self.vectors == "own" and ctx.get("mv0") is not None:
                # frame 0's surfaces keep moving as they did: at time a, q shows
                # frame 0 at q + a * mv0(q)
                color, depth = mv_warp(ctx["color0"], ctx["depth0"], ctx["mv0"], a,
                                       self.filter, raw_depth_flow=False)
            elif a <= 0.5:
                color, depth = mv_warp(ctx["color0"], ctx["depth0"], mv1, a, self.filter)
            else:
                color, depth = mv_warp(ctx["color1"], ctx["depth1"], mv1, -(1.0 - a),
                                       self.filter)
        else:
            color, depth = mv_warp(ctx["color1"], ctx["depth1"], mv1, a, self.filter)
        mv = _scaled_mv(ctx)
        return {"color": color, "depth": depth, "mv": mv}
