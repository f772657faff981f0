"""Super-resolution stages (mode "sr"): one rendered low-resolution frame in, its
high-resolution reconstruction out. The runner (fgcli.sr.Reconstructor) upsamples the
frame's depth and vectors first (ctx depth_hr / mv_hr: nearest surface of the 2x2 LR
samples, vectors scaled) and walks the rendered frames in order; recurrent state (the HR
history) lives in ctx["state"].store and never crosses a scene cut."""
from __future__ import annotations

from fgcli.stages.base import Option, Stage, register

SR_INPUTS = ("color1", "depth_hr", "mv_hr", "jitter1", "scale")


def _geometry(ctx) -> dict:
    return {"depth": ctx["depth_hr"], "mv": ctx["mv_hr"]}


@register
class Upscale(Stage):
    name = "upscale"
    help = ("Bicubic (Catmull-Rom) upscale of each rendered frame by --scale, reading every "
            "low-resolution sample at its jittered place (ringing clamped to the 2x2 nearest "
            "samples).")
    inputs = SR_INPUTS
    outputs = ("color", "depth", "mv")

    def run(self, ctx):
        from fgcli.ops.sr import upscale

        return {"color": upscale(ctx["color1"], ctx["scale"], ctx["jitter1"]), **_geometry(ctx)}


class _Recurrent(Stage):
    inputs = SR_INPUTS
    outputs = ("color", "depth", "mv")
    history = None  # the HR history depends on every earlier rendered frame

    def _state(self, ctx) -> dict:
        return ctx["state"].store.setdefault(f"sr:{self.name}", {})

    def step(self, ctx, st: dict):
        """The HR colour; may keep more state in st (besides color, depth, size)."""
        raise NotImplementedError

    def run(self, ctx):
        st = self._state(ctx)
        size = tuple(ctx["depth_hr"].shape[-2:])
        if st.get("size") != size:  # a new size (or the first frame): no history
            st.clear()
        color = self.step(ctx, st)
        st.update(color=color, depth=ctx["depth_hr"], size=size)
        return {"color": color, **_geometry(ctx)}


@register
class TAAU(_Recurrent):
    name = "taau"
    help = ("TAA upsampling: the HR history reprojected by the vectors (Catmull-Rom), "
            "rejected off-screen and where a nearer surface covered it, clamped to the 3x3 "
            "LR neighbourhood's colour range, blended with the current frame's estimate "
            "(the jitter-aware Catmull-Rom upscale, or current=gaussian: the 3x3 jittered "
            "LR samples weighted exp(-2.29 d^2), d in HR pixels) by an accumulated per-pixel "
            "weight (an average while the history is young, exponential once it is capped). "
            "First frame and rejected pixels: the bicubic upscale.")
    options = (Option("blend", "float", 0.3, "weight of the new samples once the history "
                      "has converged (its weight is capped at 1/blend - 1)",
                      range=(0.01, 1.0)),
               Option("t_d", "float", 0.02, "relative depth difference at which a nearer "
                      "surface in the history rejects it", range=(0.0, 10.0)),
               Option("history_filter", "choice", "catmull-rom", "resampling of the "
                      "reprojected history", choices=("catmull-rom", "bilinear")),
               Option("current", "choice", "catmull-rom", "the current frame's estimate: "
                      "catmull-rom (the jitter-aware upscale) or gaussian (UE's "
                      "Blackman-Harris fit over the 3x3 LR samples)",
                      choices=("catmull-rom", "gaussian")),
               Option("reactive", "float", 0.25, "drop the history where its brightness "
                      "differs from the current samples by more than this x their spread "
                      "(shading the vectors do not explain); 0 = off; chosen on held-out "
                      "random scenes", range=(0.0, 100.0)))

    def step(self, ctx, st):
        from fgcli.ops.sr import taau

        color, st["weight"] = taau(ctx["color1"], ctx["depth_hr"], ctx["mv_hr"], ctx["scale"],
                                   ctx["jitter1"], st.get("color"), st.get("depth"),
                                   st.get("weight"), blend=self.blend, t_d=self.t_d,
                                   history_filter=self.history_filter,
                                   reactive=self.reactive or None, current=self.current)
        return color


@register
class MobFGSRSR(_Recurrent):
    name = "mobfgsr_sr"
    help = ("Mob-FGSR super resolution (Sec. 3.5, Eq. 2): HR history warped with the "
            "Catmull-Rom LUT (32 phases, 4x4 taps), rejected where disoccluded, clamped "
            "to the 3x3 LR colour AABB, blended q = a * c + (1 - a) * q_w with c the LUT "
            "resampling of the jittered input (samples=eq2: the paper's distance-weighted "
            "LR samples within one LR pixel) and the history's share dropped where its "
            "shading departs from c. First frame and rejected pixels: the LUT resampling. "
            "The paper's exact reading: samples=eq2,clamp=changed,reactive=0.")
    options = (Option("a", "float", 0.34, "Eq. 2 weight of the current samples",
                      range=(0.0, 1.0)),
               Option("b", "float", 0.81, "Eq. 2 distance fall-off of a sample's weight "
                      "(samples=eq2)", range=(0.0, 1.0)),
               Option("t_d", "float", 0.02, "relative depth difference that rejects the "
                      "history (linear depth)", range=(0.0, 10.0)),
               Option("t_b", "float", 0.13, "brightness difference above which the history "
                      "is clamped to the AABB (clamp=changed)", range=(0.0, 10.0)),
               Option("phases", "int", 32, "sub-pixel phases of the Catmull-Rom LUT",
                      range=(1, 4096)),
               Option("samples", "choice", "lut", "the current frame's estimate: lut (the "
                      "Catmull-Rom LUT resampling of the jittered input) or eq2 (the "
                      "paper's sum (1 - b d_s) s over the LR samples within one LR pixel)",
                      choices=("lut", "eq2")),
               Option("clamp", "choice", "always", "clamp the history to the 3x3 LR colour "
                      "AABB always (as TAA does) or only where its brightness differs by "
                      "more than t_b (changed: the paper's T_B test)",
                      choices=("always", "changed")),
               Option("normalize", "bool", True, "divide Eq. 2's sum by the sum of its "
                      "weights (false: by the sample count n, as printed in the paper; "
                      "samples=eq2)"),
               Option("reactive", "float", 0.25, "fgen addition (0: off): drop the history "
                      "where it differs from the current estimate by more than this x the "
                      "spread of the 3x3 samples, as taau does (shading the vectors do not "
                      "explain)", range=(0.0, 100.0)))

    def step(self, ctx, st):
        from fgcli.ops.sr import mobfgsr_sr

        return mobfgsr_sr(ctx["color1"], ctx["depth_hr"], ctx["mv_hr"], ctx["scale"],
                          ctx["jitter1"], st.get("color"), st.get("depth"), a=self.a, b=self.b, t_d=self.t_d,
                          t_b=self.t_b, phases=self.phases, normalize=self.normalize,
                          reactive=self.reactive or None, samples=self.samples,
                          clamp=self.clamp)
