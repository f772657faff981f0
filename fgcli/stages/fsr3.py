"""FSR 3 frame interpolation stages (pipelines/fsr3-interp.toml): thin wrappers over
fgcli.ops.fsr3 and fgcli.ops.pyramid, one per pass of the FidelityFX document."""
from __future__ import annotations

from fgcli.stages.base import Option, Stage, register


def _no_motion(facts):
    return not facts["any_motion"]


@register
class FSR3Depth(Stage):
    name = "fsr3_depth"
    uses_kernels = True
    help = ("FSR 3 depth reconstruction: frame 1's dilated depth splatted over the bilinear "
            "footprint of p + mv (previous frame) and p + (1 - alpha) mv (interpolated frame), "
            "atomic min; vectors < 0.1 px zeroed.")
    inputs = ("depth1_d", "mv1_d", "alpha")
    outputs = ("depth_prev_r", "depth_t")
    options = (Option("short_mv", "float", 0.1, "vectors shorter than this (px) are zeroed",
                      range=(0.0, 10.0)),)

    def needed(self, ctx, facts):
        if _no_motion(facts):
            return False, "no motion: both reconstructions are the dilated depth"
        return True, ""

    def skip(self, ctx):
        from fgcli.ops import sanitize_depth

        d = sanitize_depth(ctx["depth1_d"])
        return {"depth_prev_r": d, "depth_t": d}

    def run(self, ctx):
        from fgcli.kernels import op

        dp, dt = op("reconstruct_depths", ctx)(ctx["depth1_d"], ctx["mv1_d"], ctx["alpha"],
                                               self.short_mv)
        return {"depth_prev_r": dp, "depth_t": dt}


@register
class FSR3GameField(Stage):
    name = "fsr3_game_field"
    uses_kernels = True
    help = ("FSR 3 game-MV field of the interpolated frame: 16-bit priority (primary flag, "
            "10-bit depth priority, 5-bit luminance agreement) | half-float component, atomic "
            "max into the bilinear footprint of p + (1 - alpha) mv; secondary entries stepping "
            "back toward p.")
    inputs = ("color0", "color1", "depth1_d", "mv1_d", "alpha")
    outputs = ("game_field", "field_luma0")
    options = (Option("secondary", "bool", True, "write secondary vectors"),
               Option("max_secondary", "int", 64, "longest secondary walk (px)", range=(0, 4096)))

    def needed(self, ctx, facts):
        if _no_motion(facts):
            return False, "no motion: every texel holds its own zero vector"
        return True, ""

    def skip(self, ctx):
        import torch

        from fgcli.ops.fsr3 import pack_entries

        d = ctx["depth1_d"]
        z = torch.zeros(2, *d.shape[-2:], device=d.device)
        one = torch.ones(1, *d.shape[-2:], dtype=torch.int64, device=d.device)
        # zero vectors everywhere, all primary (downstream reads vec = 0, valid = True,
        # exactly what running gives; the priorities only weight hole filling, and there
        # are no holes)
        return {"game_field": torch.cat([pack_entries(True, one, one * 0, z[c:c + 1])
                                         for c in (0, 1)]), "field_luma0": None}

    def run(self, ctx):
        from fgcli.kernels import op

        # (the priorities: depth_priority of the dilated depth)
        vector_field = op("game_vector_field", ctx)
        # frame 0's luminance plane, which the optical-flow field reads too
        l0 = op("field_luminance", ctx)(ctx["color0"])
        # the per-frame facts' largest vector component (GPU path) bounds the walk
        m = (ctx.get("facts") or {}).get("mv1_absmax")
        return {"game_field": vector_field(ctx["color0"], ctx["color1"], ctx["mv1_d"],
                                           ctx["depth1_d"], ctx["alpha"], self.secondary,
                                           self.max_secondary,
                                           length_bound=None if m is None else m * 2 ** 0.5,
                                           luma0=l0),
                "field_luma0": l0}


@register
class FSR3FieldFill(Stage):
    name = "fsr3_field_fill"
    help = ("FSR 3 vector-field inpainting: unwritten texels take the first coarser level of "
            "the priority-weighted mip pyramid of valid vectors (shared pyramid op).")
    inputs = ("game_field",)
    outputs = ("game_mv", "game_holes")
    uses_kernels = True

    def run(self, ctx):
        from fgcli.kernels import op
        out, valid = op("fill_packed_field", ctx)(ctx["game_field"])
        return {"game_mv": out, "game_holes": ~valid}


@register
class FSR3OpticalFlow(Stage):
    name = "fsr3_optical_flow"
    uses_kernels = True
    help = ("FfxOpticalFlow: 8-bit luminance pyramid, 8x8 blocks, SAD search -8..+7 coarse to "
            "fine, 3x3 vector median, 1/8 resolution (flow=block); or OpenCV DIS flow "
            "(flow=dis, a stand-in, labelled). Then the optical-flow vector field of the "
            "interpolated frame (magnitude priority, atomic max): on the block grid, "
            "sampled bilinearly per pixel, as the FidelityFX SDK (field=block), or per pixel "
            "with a pyramid fill (field=pixel).")
    inputs = ("color0", "color1", "alpha")
    optional_inputs = ("state", "number0", "number1", "field_luma0")
    outputs = ("of_mv",)
    options = (
        Option("flow", "choice", "block", "block = FfxOpticalFlow-style block matching; dis = "
               "OpenCV DIS (stand-in)", choices=("block", "dis")),
        Option("levels", "int", 7, "pyramid levels (block)", range=(1, 12)),
        Option("search", "int", 8, "search offsets -search..search-1 per level (block)",
               range=(1, 32)),
        Option("median", "bool", True, "3x3 vector-median filter per level (block)"),
        Option("subpixel", "bool", False, "sub-pixel refinement at the finest level: parabola "
               "vertex of the SAD around the integer vector, per axis (block)"),
        Option("min_flow", "float", 0.0, "flow vectors this short or shorter (px) are zeroed "
               "before the vector field (field=block skips vectors of 1 px or less anyway, "
               "as the FidelityFX SDK does)", range=(0.0, 64.0)),
        Option("field", "choice", "pixel", "block = the vector field at the flow's "
               "resolution, one texel per 8x8 block, sampled bilinearly per pixel (the "
               "FidelityFX SDK's); pixel = the flow upsampled to pixels, a field per pixel "
               "with its holes filled from a mip pyramid (flow=dis always)", choices=("block", "pixel")),
        Option("smooth", "bool", True, "field=block: the SDK's 3x3 filter of the block "
               "vectors before the field (weighted by length and agreement with the "
               "neighbours' mean)"),
    )

    def run(self, ctx):
        from fgcli.kernels import op
        from fgcli.ops.fsr3 import dis_flow, flow_vector_field, magnitude_priority

        c0, c1 = ctx["color0"], ctx["color1"]
        h, w = c1.shape[-2:]
        # the flow depends on the pair only: with --factor N it is computed once for the
        # N - 1 generated frames of a pair, and frame 1's luminance serves the next pair
        # (the runner's per-sequence state; cleared at a scene cut)
        n0, n1 = ctx.get("number0"), ctx.get("number1")
        st = ctx.get("state")
        memo = None
        if st is not None and n0 is not None and n1 is not None:
            memo = st.store.setdefault("fsr3_flow", {})
        key = (n0, n1, str(c1.device), self.flow, self.levels, self.search, self.median,
               self.subpixel, self.min_flow)
        if memo is not None and memo.get("pair") == key:
            f, hi = memo["f"], memo["hi"]
        else:
            # (the block search reads bytes: luma8's whole numbers 0..255 as uint8)
            luma8 = op("luma8" if self.flow == "dis" else "luma8_u8", ctx)
            lp = ctx.get("field_luma0")
            if memo is not None and memo.get("luma", (None,))[0] == (n0, key[2], self.flow):
                l0 = memo["luma"][1]  # frame 0 was the last pair's frame 1
            elif lp is not None and self.flow != "dis":
                # the same bytes from the game field's luminance plane of frame 0 (one
                # plane read instead of three channels)
                l0 = op("luma8_u8_of", ctx)(lp)
            else:
                l0 = luma8(c0)
            l1 = luma8(c1)
            f = dis_flow(l0, l1) if self.flow == "dis" else \
                op("block_flow", ctx)(l0, l1, self.levels, 8, self.search, self.median,
                                      self.subpixel)
            if self.min_flow > 0:
                f = f * ((f * f).sum(dim=0, keepdim=True).sqrt() > self.min_flow)
            hi = magnitude_priority(f)
            if memo is not None:
                memo.update(pair=key, f=f, hi=hi, luma=((n1, key[2], self.flow), l1))
        if self.flow != "dis" and self.field == "block":
            # the SDK's: the field on the block grid (32,400 texels at 1080p; torch on both
            # backends), sampled per pixel
            field = flow_vector_field(c0, c1, f, ctx["alpha"], 8, smooth=self.smooth)
            return {"of_mv": op("sample_flow_field", ctx)(field, h, w, 8)}
        # per block (each pixel takes its block's vector and priority), or per pixel (dis)
        field = op("vector_field", ctx)(c0, c1, f, hi, ctx["alpha"], secondary=False,
                                        block=1 if self.flow == "dis" else 8,
                                        luma0=ctx.get("field_luma0"))
        return {"of_mv": op("fill_packed_field", ctx)(field)[0]}


@register
class FSR3Disocclusion(Stage):
    name = "fsr3_disocclusion"
    help = ("FSR 3 disocclusion masks toward the previous and the current frame: bilinear "
            "depth taps, same surface when Ksep*Kfov*width*min(z)/|dz| >= 1 (Kfov from the "
            "camera's fov, else fov_default).")
    inputs = ("depth_t", "depth_prev_r", "depth1_d", "game_mv", "alpha")
    optional_inputs = ("camera1",)
    outputs = ("mask_prev", "mask_cur")
    uses_kernels = True
    options = (Option("ksep", "float", 1.37e-5, "minimum-separation constant Ksep",
                      range=(0.0, 1.0)),
               Option("fov_default", "float", 60.0, "vertical fov (degrees) when the frame has "
                      "no camera", range=(1.0, 179.0)))

    def needed(self, ctx, facts):
        if _no_motion(facts):
            return False, "no motion: every pixel is the same surface in both frames"
        return True, ""

    def skip(self, ctx):
        import torch

        d = ctx["depth_t"]
        one = torch.ones(1, *d.shape[-2:], device=d.device)
        return {"mask_prev": one, "mask_cur": one.clone()}

    def run(self, ctx):
        from fgcli.kernels import op
        from fgcli.ops.fsr3 import camera_kfov

        d = ctx["depth_t"]
        cam = ctx.get("camera1")
        kfov = camera_kfov(None if cam is None else cam.projection, d.shape[-1], d.shape[-2],
                           self.fov_default)
        mp, mc = op("disocclusion_masks", ctx)(d, ctx["depth_prev_r"], ctx["depth1_d"],
                                               ctx["game_mv"], ctx["alpha"], kfov, self.ksep)
        return {"mask_prev": mp, "mask_cur": mc}


@register
class FSR3Interpolate(Stage):
    name = "fsr3_interpolate"
    help = ("FSR 3 interpolation: lerp of the game-vector samples by the disocclusion masks, "
            "the same with optical-flow vectors, mixed by the colour-similarity bias "
            "clamp(S_game / S_of, 0, 1); both masks 0 -> hole. Also the generated depth and MVs.")
    inputs = ("color0", "color1", "game_mv", "mask_prev", "mask_cur", "depth_t", "alpha")
    optional_inputs = ("of_mv", "depth0", "depth1", "prev_time")
    outputs = ("color", "depth", "mv", "fsr3_holes", "fsr3_bias")
    uses_kernels = True
    options = (Option("space", "choice", "linear", "colour space of the samples, the "
                      "similarity and the lerps: linear, or display = the sRGB-encoded back "
                      "buffers FSR 3 interpolates (extended above 1 for HDR, decoded after)",
                      choices=("linear", "display")),)

    def run(self, ctx):
        from fgcli.kernels import op

        a = ctx["alpha"]
        v = ctx["game_mv"]  # (each op sanitises the vectors it reads)
        color, holes, bias = op("interpolate_fsr3", ctx)(ctx["color0"], ctx["color1"], v,
                                                         ctx["mask_prev"], ctx["mask_cur"], a,
                                                         ctx.get("of_mv"), self.space)
        # nothing splatted (and sky): the nearer of the two sampled depths
        depth = op("interpolated_depth", ctx)(ctx["depth_t"], v, a, ctx.get("depth0"),
                                              ctx.get("depth1"))
        prev = float(ctx.get("prev_time") or 0.0)
        # q + alpha v is where the surface was at time 0; toward the previous output time
        mv = op("output_vectors", ctx)(v, (a - prev) if a > prev else a)
        return {"color": color, "depth": depth, "mv": mv, "fsr3_holes": holes,
                "fsr3_bias": bias}


@register
class FSR3Inpaint(Stage):
    name = "fsr3_inpaint"
    help = ("FSR 3 colour inpainting: hole pixels take the (1 - i/10)^3-weighted blend of the "
            "coarser levels of the weighted mip pyramid of the valid interpolated colour "
            "(shared pyramid op).")
    inputs = ("color", "fsr3_holes")
    outputs = ("color",)
    uses_kernels = True
    options = (Option("decay", "float", 10.0, "level-weight falloff: (1 - i/decay)^3",
                      range=(1.0, 64.0)),)

    def needed(self, ctx, facts):
        from fgcli.ops._util import any_set, reads_back

        if reads_back(ctx["fsr3_holes"]) and not any_set(ctx["fsr3_holes"]):
            return False, "no holes"
        return True, ""

    def skip(self, ctx):
        return {"color": ctx["color"]}

    def run(self, ctx):
        from fgcli.kernels import op

        # in place: the interpolation's colour is this frame's alone (marked scratch by the
        # numba op); the sanitising copy cost ~2.5 ms per 1080p frame
        return {"color": op("inpaint_color", ctx)(ctx["color"], ctx["fsr3_holes"], self.decay,
                                                  in_place=True)}
