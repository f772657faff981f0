"""Stages shared by mob-fgsr and later pipelines: dilate, splat, gap fill, extrapolation hole
fill, warp, bidirectional blend, generated-frame motion. Thin wrappers over fgcli.ops."""
from __future__ import annotations

from fgcli.stages.base import Option, Stage, register


class _HoleStage(Stage):
    """A stage that refines ctx["motion"] where it has holes: not needed without holes."""

    def needed(self, ctx, facts):
        from fgcli.ops._util import all_set, reads_back

        valid = ctx["motion"].valid
        if not reads_back(valid):  # GPU: runs (dense, cheap) rather than read a value back
            return True, ""
        if all_set(valid):
            return False, "no holes left in the splatted motion"
        return True, ""

    def skip(self, ctx):
        return {"motion": ctx["motion"]}


@register
class Dilate(Stage):
    name = "dilate"
    uses_kernels = True
    help = "3x3 nearest-depth dilation of frame 1's depth and MVs (Mob-FGSR, FSR 3)."
    inputs = ("depth1", "mv1")
    outputs = ("depth1_d", "mv1_d")
    options = (Option("radius", "int", 1, "window radius (1 = 3x3)", range=(0, 3)),)

    def needed(self, ctx, facts):
        if not facts["any_motion"]:
            return False, "no motion: dilation would not change the splat"
        return self.radius > 0, "radius 0"

    def skip(self, ctx):
        return {"depth1_d": ctx["depth1"], "mv1_d": ctx["mv1"]}

    def run(self, ctx):
        from fgcli.kernels import op

        d, m = op("dilate_nearest_depth", ctx)(ctx["depth1"], ctx["mv1"], self.radius)
        return {"depth1_d": d, "mv1_d": m}


@register
class Splat(Stage):
    name = "splat"
    uses_kernels = True
    help = ("Depth-aware forward splat of frame 1's motion to the generated time, nearest "
            "surface wins (packed int64 keys, scatter_reduce amin).")
    inputs = ("depth1_d", "mv1_d", "alpha", "mode")
    optional_inputs = ("mv0", "depth0")
    outputs = ("motion",)
    options = (
        Option("motion", "choice", "auto", "motion model: auto = quadratic for interpolation, "
               "linear for extrapolation (as the public Mob-FGSR code)",
               choices=("auto", "linear", "quadratic")),
        Option("mv0_depth_check", "bool", False, "quadratic model: use frame 0's vector only "
               "where frame 0's depth agrees with the surface (fgen extension; the paper does "
               "not check)"),
        Option("mv0_depth_tol", "float", 0.05, "relative depth tolerance of that check",
               range=(0.0, 10.0)),
    )

    def model(self, mode: str) -> str:
        if self.motion == "auto":
            return "quadratic" if mode == "interp" else "linear"
        return self.motion

    def needed(self, ctx, facts):
        if not facts["any_motion"]:
            return False, "no motion: identity splat"
        return True, ""

    def skip(self, ctx):
        import torch

        from fgcli.ops import SplatResult

        d = ctx["depth1"]
        H, W = d.shape[-2:]
        z = torch.zeros(2, H, W, dtype=torch.float32, device=d.device)
        return {"motion": SplatResult(
            to1=z, to0=z.clone(), depth=d, valid=torch.ones(1, H, W, dtype=torch.bool, device=d.device),
            source=torch.arange(H * W, dtype=torch.int32, device=d.device).view(1, H, W),
            alpha=ctx["alpha"],
            mode=ctx["mode"])}

    def run(self, ctx):
        from fgcli.kernels import op

        splat_motion = op("splat_motion", ctx)
        model = self.model(ctx["mode"])
        mv0 = ctx.get("mv0") if model == "quadratic" else None
        d0 = ctx.get("depth0") if (mv0 is not None and self.mv0_depth_check) else None
        # an extrapolation samples frame 1 only: no offsets toward frame 0 (their plane
        # pair cost ~80 MB of traffic per 1080p frame through the splat and the fills)
        return {"motion": splat_motion(ctx["depth1_d"], ctx["mv1_d"], mv0, ctx["alpha"],
                                       model="linear" if mv0 is None else model,
                                       mode=ctx["mode"], depth0=d0,
                                       depth0_tol_rel=self.mv0_depth_tol,
                                       toward0=ctx["mode"] == "interp")}


@register
class GapFill(_HoleStage):
    name = "gap_fill"
    uses_kernels = True
    help = ("Mob-FGSR refinement: fill splat cracks inside nearer surfaces (2x2-block rule); "
            "remaining holes fall back to linear motion of the previous vector.")
    inputs = ("motion",)
    optional_inputs = ("mv0", "mv1", "depth1")
    outputs = ("motion",)
    options = (
        Option("depth_threshold", "float", 0.01, "relative depth margin for 'nearer' "
               "neighbours", range=(0.0, 1.0)),
        Option("fill", "choice", "nearest", "candidate to copy: nearest (public code) or mean "
               "(paper wording)", choices=("nearest", "mean")),
        Option("fallback", "choice", "prev_mv", "holes left after refinement: linear motion of "
               "the previous vector (frame 0's in interpolation) or leave empty",
               choices=("prev_mv", "none")),
    )

    def needed(self, ctx, facts):
        # The refinement also rewrites valid pixels: a background sample showing through a
        # crack in a nearer surface. So "no holes" alone does not make it a no-op. Without
        # motion the splat is skipped (the identity), and so is the fill: every vector is
        # zero, so the fill could only relabel a far pixel's depth and source, and the
        # output frame is the input either way (tests/test_pipeline.py).
        if facts.get("any_motion", True) or facts.get("history_motion", False):
            return True, ""
        return super().needed(ctx, facts)

    def run(self, ctx):
        from fgcli.kernels import op

        gap_fill = op("gap_fill", ctx)
        fb = fbd = None
        if self.fallback == "prev_mv" and ctx["mode"] == "interp":
            # holes are surfaces only frame 0 sees: its vectors and depth
            has0 = ctx.get("mv0") is not None
            fb = ctx["mv0"] if has0 else ctx["mv1"]
            fbd = ctx["depth0"] if ctx.get("depth0") is not None else ctx["depth1"]
        # in place: the splat's planes are this frame's alone (SplatResult.scratch); the
        # copy to fresh planes cost ~2.5 ms per 1080p frame
        return {"motion": gap_fill(ctx["motion"], self.depth_threshold, self.fill, fb, fbd,
                                   in_place=True)}


@register
class ExtrapHoleFill(_HoleStage):
    name = "extrap_fill"
    uses_kernels = True
    help = ("Mob-FGSR extrapolation disocclusion rule: a hole takes frame 1's vector at the "
            "pixel if the surface it points to is background, else zero motion.")
    inputs = ("motion", "mv1", "depth1_d")
    outputs = ("motion",)
    options = (Option("depth_threshold", "float", 1e-3, "relative depth margin", range=(0.0, 1.0)),)

    def run(self, ctx):
        from fgcli.kernels import op

        return {"motion": op("fill_extrap_holes", ctx)(ctx["motion"], ctx["mv1"], ctx["depth1_d"],
                                                       self.depth_threshold, in_place=True)}


@register
class Warp(Stage):
    name = "warp"
    uses_kernels = True
    help = "Backward-warp the rendered frames (color and depth) along the generated motion."
    inputs = ("motion", "color1", "depth1")
    optional_inputs = ("color0", "depth0")
    outputs = ("s0", "s1", "sd0", "sd1", "v0", "v1")
    options = (Option("filter", "choice", "bilinear", "resampling filter",
                      choices=("bilinear", "catmull-rom", "nearest")),)

    def needed(self, ctx, facts):
        m = ctx["motion"]
        from fgcli.ops._util import reads_back

        if (not facts["any_motion"] and reads_back(m.to1) and not bool(m.to1.any())
                and (m.to0 is None or not bool(m.to0.any()))):
            return False, "zero motion: samples are the rendered frames"
        return True, ""

    def skip(self, ctx):
        import torch

        from fgcli.ops import sanitize_depth, sanitize_values

        c1, c0, d0 = ctx["color1"], ctx.get("color0"), ctx.get("depth0")
        ones = torch.ones(1, *c1.shape[-2:], dtype=torch.bool, device=c1.device)
        return {"s0": None if c0 is None else sanitize_values(c0), "s1": sanitize_values(c1),
                "sd0": None if d0 is None else sanitize_depth(d0),
                "sd1": sanitize_depth(ctx["depth1"]), "v0": ones, "v1": ones}

    def run(self, ctx):
        from fgcli.kernels import op

        m = ctx["motion"]
        two = ctx["mode"] == "interp"
        s1, v1, sd1, s0, v0, sd0 = op("warp_frames", ctx)(
            ctx["color1"], ctx["depth1"], m.to1, ctx["color0"] if two else None,
            ctx["depth0"] if two else None, m.to0 if two else None, self.filter)
        return {"s1": s1, "v1": v1, "sd1": sd1, "s0": s0, "sd0": sd0, "v0": v0}

    def fuse(self, nxt, ctx, facts):
        """Interpolation with the kernels: this warp and the blend that follows it in one
        pass (fgcli.kernels.ops.warp_blend: the samples stay in row buffers; 1080p: ~2 ms
        less than the two stages). The samples (s0, s1, ...) are then not kept."""
        if not isinstance(nxt, Blend) or ctx.get("backend") != "numba" or \
                ctx["mode"] != "interp" or self.filter != "bilinear":
            return None
        from fgcli.kernels import op

        m = ctx["motion"]
        res = op("warp_blend", ctx)(ctx["color1"], ctx["depth1"], m.to1, ctx["color0"],
                                    ctx["depth0"], m.to0, *nxt.blend_args(ctx))
        if res is None:
            return None
        return {"color": res[0], "depth": res[1]}


@register
class Blend(Stage):
    name = "blend"
    uses_kernels = True
    help = ("Mob-FGSR Eq. 1 bidirectional blend: same surface and similar brightness -> "
            "temporally nearer frame, else lerp by alpha; different surfaces -> farther "
            "(disoccluded background). Extrapolation: the frame-1 sample.")
    inputs = ("s1", "sd1", "v1", "alpha", "mode")
    optional_inputs = ("s0", "sd0", "v0", "motion")
    outputs = ("color", "depth")
    options = (
        Option("t_d", "float", 0.02, "depth agreement threshold, relative to linear depth "
               "(paper: 0.0028 on [0,1] device depth)", range=(0.0, 10.0)),
        Option("t_b", "float", 0.13, "brightness agreement threshold (paper: 0.13, on sRGB)",
               range=(0.0, 10.0)),
        Option("target_depth", "bool", False, "prefer the sample whose depth matches the "
               "splatted depth when the two disagree (fgen extension)"),
        Option("static_crossfade", "bool", True, "shading motion: where the pixel's surface "
               "does not move and the depths agree, cross-fade instead of taking one frame "
               "(fgen extension, default since it never lost on the bundled scenes: shadows "
               "+5.2 dB; the paper's Eq. 1: static_crossfade=false)"),
    )

    def run(self, ctx):
        from fgcli.kernels import op

        if ctx["mode"] == "extrap":
            return {"color": ctx["s1"], "depth": ctx["sd1"]}
        # the generated frame's depth follows the same per-pixel choice as its color
        color, depth = op("blend_eq1", ctx)(
            ctx["s0"], ctx["s1"], ctx["sd0"], ctx["sd1"], ctx["v0"], ctx["v1"],
            *self.blend_args(ctx))
        return {"color": color, "depth": depth}

    def blend_args(self, ctx):
        """(d_target, alpha, t_d, t_b, static_from) of blend_eq1 (and of the warp's fused
        pass, Warp.fuse)."""
        m = ctx.get("motion")
        dt = m.depth if self.target_depth and m is not None else None
        # static cross-fade: pixels whose surface sits still from frame 0 to frame 1
        # (no motion; fgcli.kernels.reference.static_mask)
        return dt, ctx["alpha"], self.t_d, self.t_b, m if self.static_crossfade else None


@register
class MotionOut(Stage):
    name = "motion_out"
    help = ("MVs of the generated frame (toward the previous output frame, linear in time "
            "within the interval), so a downstream TAA/upscaler can consume it.")
    inputs = ("motion", "alpha", "mode")
    optional_inputs = ("prev_time",)
    outputs = ("mv",)
    options = ()

    def run(self, ctx):
        from fgcli.ops import generated_mv

        m = ctx["motion"]
        a = ctx["alpha"]
        prev = float(ctx.get("prev_time") or 0.0)
        mv = generated_mv(m, copy=False)  # stage outputs are never modified in place
        if a > 0 and prev > 0:
            mv = mv * ((a - prev) / a)
        return {"mv": mv}
