"""GFFE geometry-aware extrapolation (GAE) stages (pipelines/gffe-extrap.toml): history
tracking, camera extrapolation + adaptive window, position estimation, warp, background
collection and projection, hole fill. Thin wrappers over fgcli.ops.gffe; with --backend
numba the ops that unproject / project pixels get them from the numba kernels
(fgcli.kernels.geom, bit-identical), through op().

Recurrent state (trajectories, background layers, their camera) lives in the runner's
RunState (ctx["state"].store["gffe"]), updated once per rendered frame (the first job of a
rendered frame; --count N makes N jobs per frame) and cleared by the runner at a scene cut.
Without a RunState (a single call), the state lives for that call only.
"""
from __future__ import annotations

from fgcli.errors import InputError, UsageError
from fgcli.kernels import op
from fgcli.stages.base import Option, Stage, register

KEY = "gffe"


def _store(ctx) -> dict:
    st = ctx.get("state")
    if st is None:
        return ctx.setdefault("_gffe_local", {})
    return st.store.setdefault(KEY, {})


def _need_camera(ctx, stage: str):
    if ctx.get("camera1") is None:
        raise InputError(f"gffe-extrap ({stage}) needs per-frame cameras (world_to_camera + "
                         "projection: EXR worldToCamera/worldToNDC, fgen:* header attributes "
                         "or cameras.json); this input has none. Use a motion-vector "
                         "pipeline (mob-fgsr, mv-warp) for footage without cameras.")


def _frame_id(ctx):
    return ctx.get("number1")


def torch_equal(a, b) -> bool:
    import torch

    return bool(torch.equal(a, b))


def _still(ctx) -> bool:
    """The extrapolated camera is frame 1's (both matrices equal: a camera that did not
    move, fgcli.ops.gffe.extrapolate_camera)."""
    import numpy as np

    from fgcli.ops.gffe import _mats

    c1 = ctx.get("camera1")
    if c1 is None:
        return False
    (vx, px), (v1, p1) = _mats(ctx["camera_x"]), _mats(c1)
    return bool(np.array_equal(vx, v1) and np.array_equal(px, p1))


def _static_frame(ctx, facts) -> bool:
    """Static camera and no motion vectors: every pixel passes the static test."""
    return (not facts.get("camera_moved", False)) and not facts.get("any_motion", True)


@register
class GffeHistory(Stage):
    name = "gffe_history"
    help = ("GFFE Algorithm 1: per-pixel trajectory of k world positions from unprojected "
            "depth and cameras; the static test compares the camera-only reprojection with "
            "the MV reprojection. Runs once per rendered frame; state in the RunState.")
    inputs = ("depth1", "mv1", "alpha")
    optional_inputs = ("camera1", "camera0", "depth0", "state", "number1")
    outputs = ("traj", "dynamic")
    options = (
        Option("k", "int", 0, "trajectory length: 2 = Eq. 1, 3 also feeds "
               "motion=quadratic; 0 = what the pipeline's position stage reads (a longer "
               "trajectory costs its copies in every frame and nothing reads them)",
               range=(0, 4)),
        Option("threshold", "float", 0.5, "static test: pixels between the camera-only and "
               "the MV reprojection above which a pixel is dynamic", range=(0.0, 1e6)),
        Option("first_frame", "choice", "mv", "empty history (first frame, after a cut): "
               "static (the paper) or mv (screen-space motion from the frame's vectors, fgen)",
               choices=("mv", "static")),
        Option("lookup", "choice", "match", "where x' (the vector's previous position) "
               "falls: nearest (the pixel containing x', the paper) or match (fgen: of the "
               "3x3 pixels around x', the one whose depth is nearest the pixel's current "
               "depth; none within match_tol: the surface was at x' at its current depth)",
               choices=("match", "nearest")),
        Option("match_tol", "float", 0.1, "lookup=match: relative depth difference above "
               "which no neighbour of x' counts as the same surface", range=(0.0, 1e6)),
    )
    history = None  # the trajectories carry over every earlier rendered frame
    uses_kernels = True

    def configure(self, built, where):
        quad = any(isinstance(st, GffePosition) and st.motion == "quadratic" for _, st in built)
        if self.opts["k"] == 0:
            self.opts["k"] = 3 if quad else 2
        elif self.opts["k"] < 2 or (quad and self.opts["k"] < 3):
            raise UsageError(f"{where}: stage '{self.name}': k = {self.opts['k']}: expected 2 "
                             f"or more (3 or more for the position stage's motion=quadratic), "
                             f"or 0 (what the position stage reads)")

    def needed(self, ctx, facts):
        _need_camera(ctx, self.name)
        s = _store(ctx)
        if s.get("hist_frame") is not None and s.get("hist_frame") == _frame_id(ctx):
            return False, "tracked once per rendered frame"
        if _static_frame(ctx, facts):
            return False, "static camera and no motion: every pixel is static"
        return True, ""

    def skip(self, ctx):
        import torch

        s = _store(ctx)
        fid = _frame_id(ctx)
        if s.get("hist_frame") is not None and s.get("hist_frame") == fid:
            return {"traj": s.get("traj"), "dynamic": s["dynamic"]}
        h, w = ctx["depth1"].shape[-2:]
        dyn = torch.zeros(1, h, w, dtype=torch.bool, device=ctx["depth1"].device)
        s.update(hist_frame=fid, traj=None, dynamic=dyn, hist_camera=ctx["camera1"])
        return {"traj": None, "dynamic": dyn}

    def run(self, ctx):
        s = _store(ctx)
        prev = s.get("traj")
        d1 = ctx["depth1"]
        cam0 = ctx.get("camera0")
        if prev is not None and tuple(prev.shape[-2:]) != tuple(d1.shape[-2:]):
            prev = None
        if ctx.get("depth0") is None and prev is None:
            cam0 = None
        traj, dyn = op("track_history", ctx)(d1, ctx["mv1"], ctx["camera1"], cam0,
                                             ctx.get("depth0"), prev, self.k, self.threshold,
                                             self.first_frame, self.lookup, self.match_tol)
        s.update(hist_frame=_frame_id(ctx), traj=traj, dynamic=dyn, hist_camera=ctx["camera1"])
        return {"traj": traj, "dynamic": dyn}


@register
class GffeCamera(Stage):
    name = "gffe_camera"
    help = ("Camera of the extrapolated frame: model=linear is GFFE Eq. 2, C + alpha "
            "(C - C_prev) per pose component; model=rigid (fgen, default) keeps the last "
            "relative rigid motion (screw motion), exact on orbits and turns. The adaptive "
            "window uses the same camera.")
    inputs = ("alpha",)
    optional_inputs = ("camera0", "camera1")
    outputs = ("camera_x",)
    options = (Option("model", "choice", "rigid", "linear: Eq. 2 (the paper); rigid: "
                      "constant relative rigid motion (fgen)", choices=("linear", "rigid")),)

    def needed(self, ctx, facts):
        _need_camera(ctx, self.name)
        if ctx.get("camera0") is None or not facts.get("camera_moved", False):
            return False, "static camera (or no previous camera): extrapolated = current"
        return True, ""

    def skip(self, ctx):
        from fgcli.ops.gffe import extrapolate_camera

        return {"camera_x": extrapolate_camera(None, ctx["camera1"], ctx["alpha"])}

    def run(self, ctx):
        from fgcli.ops.gffe import extrapolate_camera

        return {"camera_x": extrapolate_camera(ctx["camera0"], ctx["camera1"], ctx["alpha"],
                                               self.model)}


@register
class GffeWindow(Stage):
    name = "gffe_window"
    help = ("GFFE adaptive rendering window (Sec. 4.3, appendix C, Eq. 5): the window a "
            "renderer should use so the extrapolated view is covered; recorded per rendered "
            "frame in fgen-run.json (render_windows). When the input frames were rendered "
            "with an overscan border (an EXR data window beyond the display window), the "
            "border is what the hole fill reads out-of-screen disocclusions from "
            "(window=off: the display window only).")
    inputs = ("camera_x", "depth1")
    optional_inputs = ("camera1", "overscan1")
    outputs = ("render_window", "window_border")
    options = (
        Option("plane_depth", "float", 0.0, "virtual plane distance (scene units); 0 = the "
               "median finite depth of the frame", range=(0.0, 1e9)),
        Option("limit", "float", 4.0, "largest window half-extent, in nominal windows",
               range=(1.0, 100.0)),
    )

    uses_kernels = True

    def run(self, ctx):
        import math

        from fgcli.ops.gffe import render_window

        d = self.plane_depth
        if d <= 0:
            # the median of the finite positive depths (NaN when there are none): the one
            # value gffe reads back per frame on a GPU (the window is host metadata)
            d = op("median_depth", ctx)(ctx["depth1"])
            if not (d > 0 and math.isfinite(d)):
                d = 10.0
        try:
            win = render_window(ctx["camera1"], ctx["camera_x"], d, self.limit)
        except (ValueError, ArithmeticError, __import__("numpy").linalg.LinAlgError):
            win = (-1.0, -1.0, 1.0, 1.0)
        return {"render_window": [round(x, 6) for x in win],
                "window_border": ctx.get("overscan1")}


@register
class GffePosition(Stage):
    name = "gffe_position"
    help = ("GFFE Eq. 1: next world position NP = alpha (P0 - P1) + P0 (linear in world "
            "space); motion=quadratic: the higher-order ablation of the paper.")
    inputs = ("traj", "alpha")
    optional_inputs = ("dynamic", "depth1", "camera1")
    outputs = ("positions",)
    options = (Option("motion", "choice", "linear", "world-space motion model",
                      choices=("linear", "quadratic")),
               Option("dilate", "choice", "off", "fgen: Mob-FGSR's 3x3 nearest-depth dilation "
                      "in world space: a pixel takes the depth of the nearest pixel of its "
                      "3x3 window and moves as that pixel moves. dynamic: only static pixels "
                      "beside a nearer dynamic one (a moving object's rim and contact "
                      "shadow); full: every pixel (Mob-FGSR's rule; worse on held-out "
                      "scenes, docs/results.md)", choices=("off", "dynamic", "full")))
    uses_kernels = True

    def needed(self, ctx, facts):
        if ctx.get("traj") is None:
            return False, "every pixel static: positions are the unprojected depth"
        from fgcli.ops._util import any_set, reads_back

        t = ctx["traj"]
        if not reads_back(t):  # GPU: computed (same values) rather than read back
            return True, ""
        if self.dilate == "full" and facts.get("camera_moved", True):
            return True, ""
        if not any_set(ctx["dynamic"]) and torch_equal(t[0], t[1]):
            return False, "no dynamic pixels: positions are the unprojected depth"
        return True, ""

    def skip(self, ctx):
        t = ctx.get("traj")
        return {"positions": None if t is None else t[0]}

    def run(self, ctx):
        from fgcli.ops.gffe import estimate_positions

        traj = ctx["traj"]
        if traj is None:  # every pixel static (the history stage had no work)
            return self.skip(ctx)
        d1 = ctx.get("depth1")
        if self.dilate != "off" and d1 is not None and ctx.get("camera1") is not None:
            pos = op("dilated_positions", ctx)(
                traj, d1, ctx["camera1"], ctx.get("dynamic") if self.dilate == "dynamic" else None,
                ctx["alpha"], self.motion)
        else:
            pos = estimate_positions(traj, ctx["alpha"], self.motion)
        return {"positions": pos}


@register
class GffeWarp(Stage):
    name = "gffe_warp"
    help = ("GFFE warp: project the estimated positions with the extrapolated camera, "
            "nearest depth wins (packed-key splat shared with mob-fgsr); color, depth and MVs "
            "of the extrapolated frame, holes marked.")
    inputs = ("color1", "depth1", "camera_x")
    optional_inputs = ("positions", "camera1", "traj")
    outputs = ("color", "depth", "mv", "valid")
    options = (Option("filter", "choice", "bilinear", "bilinear: sample frame 1 at the "
                      "winner's sub-pixel source (fgen); nearest: the winner's own color "
                      "(the paper's splat)", choices=("bilinear", "nearest")),
               Option("crack_fill", "bool", True, "fill one-pixel splat cracks inside nearer "
                      "surfaces (Mob-FGSR's 2x2 rule, shared gap_fill op; fgen addition)"))
    uses_kernels = True

    def needed(self, ctx, facts):
        if ctx.get("positions") is None and not facts.get("camera_moved", False):
            return False, "static camera, static pixels: the rendered frame"
        return True, ""

    def skip(self, ctx):
        import torch

        from fgcli.ops import sanitize_depth, sanitize_values

        c = ctx["color1"]
        return {"color": sanitize_values(c), "depth": sanitize_depth(ctx["depth1"]),
                "mv": torch.zeros(2, *c.shape[-2:], device=c.device),
                "valid": torch.ones(1, *c.shape[-2:], dtype=torch.bool, device=c.device)}

    def run(self, ctx):
        pos = ctx.get("positions")
        origin = None
        if pos is None:
            pos = op("unproject", ctx)(ctx["depth1"], ctx["camera1"])
        elif (ctx.get("traj") is not None and ctx["traj"].shape[1:] == pos.shape
              and _still(ctx)):
            # a still camera sees P_0 (frame 1's unprojected depth) at the pixel centres:
            # a position that is its pixel's P_0 (a static pixel) stays on its pixel
            # exactly, instead of moving by the projection's float32 rounding (~1e-5 px,
            # and a bilinear read that mixes in the neighbours by as much)
            origin = ctx["traj"][0]
        out = op("warp_positions", ctx)(ctx["color1"], pos, ctx["camera_x"], self.filter,
                                        self.crack_fill, origin=origin)
        return {"color": out["color"], "depth": out["depth"], "mv": out["mv"],
                "valid": out["valid"]}


@register
class GffeBackgroundCollect(Stage):
    name = "gffe_bg_collect"
    help = ("GFFE layered background collection (Sec. 4.2, Fig. 5): two layers (full and "
            "quarter size) of static color+depth, updated once per rendered frame by the "
            "paper's two cases.")
    inputs = ("color1", "depth1", "dynamic")
    optional_inputs = ("camera1", "state", "number1")
    outputs = ("bg",)
    options = (Option("depth_tol", "float", 0.02, "relative depth margin for 'deeper'",
                      range=(0.0, 10.0)),
               Option("edge_guard", "bool", False, "keep silhouette pixels (next to a dynamic "
                      "pixel or to a nearer depth edge; their anti-aliased color mixes the "
                      "occluder in) out of layer 0, holding the older fragment there (fgen)"),
               Option("layer1_scale", "int", 2, "cells of layer 1 (the background behind "
                      "layer 0) in full pixels per side: 2 = quarter size (the paper's "
                      "L = 2), 1 = full size (fgen)", range=(1, 2)))
    history = None
    uses_kernels = True

    def needed(self, ctx, facts):
        s = _store(ctx)
        if s.get("bg_frame") is not None and s.get("bg_frame") == _frame_id(ctx):
            return False, "collected once per rendered frame"
        if s.get("bg") is not None and _static_frame(ctx, facts) and \
                tuple(s["bg"][0]["depth"].shape[-2:]) == tuple(ctx["depth1"].shape[-2:]):
            # nothing moves: no hole can appear in this frame's extrapolation, and the
            # layers already hold every fragment it shows (its shading may have changed:
            # the next collection with motion takes the new frame's own pixels again)
            return False, "static camera and no motion: the layers are kept as they are"
        return True, ""

    def skip(self, ctx):
        s = _store(ctx)
        if s.get("bg") is not None:
            s["bg_frame"] = _frame_id(ctx)
        return {"bg": s.get("bg")}

    def run(self, ctx):
        s = _store(ctx)
        prev, cam_prev = s.get("bg"), s.get("bg_camera")
        d1 = ctx["depth1"]
        if prev is not None and (tuple(prev[0]["depth"].shape[-2:]) != tuple(d1.shape[-2:]) or
                                 tuple(prev[1]["depth"].shape[-2:]) != _l1_shape(d1, self)):
            prev = None
        bg = op("collect_background", ctx)(ctx["color1"], d1, ~ctx["dynamic"], ctx["camera1"],
                                           prev, cam_prev, self.depth_tol, self.edge_guard,
                                           self.layer1_scale)
        s.update(bg=bg, bg_camera=ctx["camera1"], bg_frame=_frame_id(ctx))
        return {"bg": bg}


def _l1_shape(depth, stage) -> tuple:
    from fgcli.ops.gffe import _half

    h, w = depth.shape[-2:]
    return _half(h, w) if stage.layer1_scale == 2 else (h, w)


class _HoleStage(Stage):
    """A stage that fills holes of the warped frame (ctx["valid"] False): nothing to do
    without holes; skipped, it passes its outputs through. Its op is called with
    in_place=True: the warped planes (and each hole stage's results) are marked scratch
    by the op that made them, and the stage gives them up, so the numba ops write the
    holes they fill into them instead of copying every pixel (fgcli.ops._util)."""

    def needed(self, ctx, facts):
        from fgcli.ops._util import all_set, reads_back

        if reads_back(ctx["valid"]) and all_set(ctx["valid"]):
            return False, "no holes in the warped frame"
        return True, ""

    def skip(self, ctx):
        return {k: ctx[k] for k in self.outputs}


@register
class GffeVectorRule(_HoleStage):
    name = "gffe_vector_rule"
    help = ("Holes of the warped frame first take Mob-FGSR's extrapolation rule where it "
            "finds background: frame 1 behind the object that moved away, along the "
            "pixel's vector (current shading; fgen, the op mob-fgsr uses). Before the "
            "background layers, whose fragments may be frames old.")
    uses_kernels = True
    inputs = ("color", "depth", "mv", "valid", "color1", "depth1", "mv1", "alpha")
    outputs = ("color", "depth", "mv", "valid")
    options = (Option("depth_threshold", "float", 1e-3, "relative depth margin of the "
                      "rule's background test (mob-fgsr's extrap_fill)", range=(0.0, 1.0)),)

    def run(self, ctx):
        c, d, m, took = op("vector_rule_fill", ctx)(ctx["color"], ctx["valid"], ctx["depth"],
                                                    ctx["mv"], ctx["color1"], ctx["depth1"],
                                                    ctx["mv1"], ctx["alpha"],
                                                    self.depth_threshold, in_place=True)
        return {"color": c, "depth": d, "mv": m, "valid": ctx["valid"] | took}


@register
class GffeBackgroundProject(_HoleStage):
    name = "gffe_bg_project"
    help = ("GFFE background projection: the collected layers seen by the extrapolated "
            "camera fill only the holes of the warped frame.")
    inputs = ("color", "depth", "mv", "valid", "camera_x")
    optional_inputs = ("bg", "camera1", "color1", "depth1", "mv1", "alpha")
    outputs = ("color", "depth", "mv", "valid")
    options = (Option("filter", "choice", "nearest", "nearest: the winning fragment's color "
                      "(the paper's splat); bilinear (fgen): the full-size layer read at the "
                      "hole's exact sub-pixel place", choices=("nearest", "bilinear")),
               Option("entering", "bool", False, "fgen: where frame 1 shows a nearer surface "
                      "that came in across the border (its vector leads off-screen), that "
                      "surface (frame 1 at the pixel) rather than the layers' older fragment"),
               Option("emerging", "bool", False, "fgen, with entering: also a nearer surface "
                      "that came out from behind a still nearer one (its vector leads onto "
                      "that one)"))
    uses_kernels = True

    def needed(self, ctx, facts):
        if ctx.get("bg") is None:
            return False, "no background collected"
        return super().needed(ctx, facts)

    def run(self, ctx):
        if ctx.get("bg") is None:
            return self.skip(ctx)
        ent = self.entering and ctx.get("mv1") is not None
        c, d, m, v = op("background_fill", ctx)(
            ctx["color"], ctx["depth"], ctx["mv"], ctx["valid"], ctx["bg"], ctx["camera1"],
            ctx["camera_x"], self.filter, ctx.get("color1"), ctx.get("depth1"),
            ctx.get("mv1"), ctx["alpha"], ent, self.emerging, in_place=True)
        return {"color": c, "depth": d, "mv": m, "valid": v}


@register
class GffeHoleFill(Stage):
    name = "gffe_hole_fill"
    help = ("Remaining holes after background projection: a far-biased push-pull "
            "(validity-weighted pyramid) gives color and a background depth; mode=reproject "
            "then reads frame 1 along that proxy surface where frame 1 sees it. Zero MVs in "
            "push-pull pixels. The count goes to ctx['holes'] (fgen eval: hole_fill_fraction).")
    inputs = ("color", "depth", "mv", "valid")
    optional_inputs = ("color1", "depth1", "camera1", "camera_x", "window_border")
    outputs = ("color", "depth", "mv", "holes")
    options = (
        Option("far_bias", "float", 0.1, "pyramid levels average only pixels within this "
               "relative depth of the farthest (disocclusions show background); -1 = plain "
               "push-pull", range=(-1.0, 1.0)),
        Option("mode", "choice", "reproject", "reproject (frame 1 through the background "
               "proxy depth, else push-pull) or push_pull", choices=("reproject", "push_pull")),
        Option("offscreen", "choice", "clamp", "reproject: a point off frame 1's screen "
               "(out-of-screen disocclusion without a rendered border) reads the nearest "
               "edge pixel (clamp, fgen) or is left to the push-pull (skip)",
               choices=("clamp", "skip")),
        Option("border_splat", "bool", True, "with an overscan border (window stage on): "
               "splat the border's own fragments into the holes before the push-pull and "
               "the reprojection (GFFE's larger rendering window)"),
    )
    uses_kernels = True

    def needed(self, ctx, facts):
        from fgcli.ops._util import all_set, reads_back

        if reads_back(ctx["valid"]) and all_set(ctx["valid"]):
            return False, "no holes left"
        return True, ""

    def skip(self, ctx):
        return {"color": ctx["color"], "depth": ctx["depth"], "mv": ctx["mv"], "holes": 0}

    def run(self, ctx):
        # the count stays a tensor (no read-back on a GPU); fgen eval reads it with int();
        # in_place: as the hole stages' (_HoleStage)
        c, d, mv, holes = op("fill_holes", ctx)(
            ctx["color"], ctx["depth"], ctx["mv"], ctx["valid"], self.far_bias, self.mode,
            self.offscreen, self.border_splat, ctx.get("color1"), ctx.get("depth1"),
            ctx.get("camera1"), ctx.get("camera_x"), ctx.get("window_border"), in_place=True)
        return {"color": c, "depth": d, "mv": mv, "holes": holes}
