"""Compiled CPU kernels (numba) for the per-pixel ops, and the one dispatch point.

The torch functions in fgcli.ops (plus the fused stage compositions in
fgcli.kernels.reference) are the reference implementation and the CUDA path. With
``--backend numba`` (the default ``auto`` on CPU) a stage asks ``op(name, ctx)`` for the
implementation of an op and gets the numba kernel of fgcli.kernels.ops instead; kernels
fall back to the reference themselves for option combinations they do not implement
(batched tensors, fill='mean', catmull-rom, ...). Each op's results agree with the
reference as its contract says (fgcli.kernels.contract: decisions exact, floats within a
stated bound; docs/design.md section 7).

Importing this package does not import numba or torch (``fgen --help`` stays fast).
"""
from __future__ import annotations

import importlib.util

BACKENDS = ("auto", "torch", "numba")

# ops with a numba implementation in fgcli.kernels.ops (name -> reference module)
KERNEL_OPS = {
    "dilate_nearest_depth": "fgcli.ops",
    "splat_motion": "fgcli.ops",
    "gap_fill": "fgcli.ops",
    "fill_extrap_holes": "fgcli.ops",
    "blend_interp": "fgcli.ops",
    "blend_eq1": "fgcli.kernels.reference",
    "warp_frames": "fgcli.kernels.reference",
    "warp_blend": "fgcli.kernels.reference",
    "mv_warp": "fgcli.kernels.reference",
    "crossfade": "fgcli.kernels.reference",
    "guiding_flows": "fgcli.ops.mvinterp",
    "block_flow": "fgcli.ops.fsr3",
    "vector_field": "fgcli.ops.fsr3",
    "game_vector_field": "fgcli.ops.fsr3",
    "reconstruct_depths": "fgcli.ops.fsr3",
    # gffe: the ops whose camera geometry (unproject / project) runs in fgcli.kernels.geom
    "unproject": "fgcli.ops.gffe",
    "project": "fgcli.ops.gffe",
    "track_history": "fgcli.ops.gffe",
    "dilate_trajectory": "fgcli.ops.gffe",
    "dilated_positions": "fgcli.ops.gffe",
    "warp_positions": "fgcli.ops.gffe",
    "collect_background": "fgcli.ops.gffe",
    "project_background": "fgcli.ops.gffe",
    "background_fill": "fgcli.ops.gffe",
    "project_border": "fgcli.ops.gffe",
    "reproject_fill": "fgcli.ops.gffe",
    "fill_holes": "fgcli.ops.gffe",
    "push_pull_fill": "fgcli.ops.gffe",
    "vector_rule_fill": "fgcli.ops.gffe",
    "median_depth": "fgcli.ops.gffe",
    "disocclusion_masks": "fgcli.ops.fsr3",
    "interpolate_fsr3": "fgcli.ops.fsr3",
    "fill_packed_field": "fgcli.ops.fsr3",
    "inpaint_color": "fgcli.ops.fsr3",
    "pyramid_inpaint": "fgcli.ops.pyramid",
    "luma8": "fgcli.ops.fsr3",
    "luma8_u8": "fgcli.ops.fsr3",
    "luma8_u8_of": "fgcli.ops.fsr3",
    "depth_priority": "fgcli.ops.fsr3",
    "avg_pool2": "fgcli.ops.pyramid",
    "sample_flow_field": "fgcli.ops.fsr3",
    "interpolated_depth": "fgcli.ops.fsr3",
    "output_vectors": "fgcli.ops.fsr3",
    "field_luminance": "fgcli.ops.fsr3",
    "scene_change_score_tensor": "fgcli.ops.scene",
}


def numba_available() -> bool:
    return importlib.util.find_spec("numba") is not None


# What `auto` picks on the CPU: the kernels (the torch ops' results within each op's
# contract, 2-10x faster per 1080p frame; docs/performance.md) for frames of at least AUTO_MIN_PIXELS.
# A fresh install compiles them once into numba's on-disk cache (1-3 minutes on 2
# cores); later processes load them in < 1 s. Below that size torch eager costs a few ms
# per frame, so the one-time compilation would not pay for itself: auto stays torch there
# (`--backend numba` forces the kernels).
AUTO_CPU = "numba"
AUTO_MIN_PIXELS = 1 << 19  # 0.5 Mpx (960x540 and up)


def resolve(backend: str | None, device: str = "cpu", pixels: int | None = None) -> str:
    """--backend value -> 'torch' or 'numba'. auto: AUTO_CPU on CPU (numba only when
    installed and, when ``pixels`` (the frame area) is given, at least AUTO_MIN_PIXELS),
    torch on CUDA. numba on a CUDA device is a usage error."""
    from fgcli.errors import UsageError

    b = (backend or "auto").lower()
    if b not in BACKENDS:
        raise UsageError(f"unknown backend '{backend}' ({', '.join(BACKENDS)})")
    cuda = str(device).startswith("cuda")
    if b == "auto":
        if cuda or AUTO_CPU == "torch" or not numba_available():
            return "torch"
        if pixels is not None and pixels < AUTO_MIN_PIXELS:
            return "torch"
        return "numba"
    if b == "numba":
        if cuda:
            raise UsageError("--backend numba runs on the CPU; use --backend torch (or auto) "
                             "with --device cuda")
        if not numba_available():
            raise UsageError("--backend numba: numba is not installed (pip install numba)")
    return b


def op(name: str, ctx: dict | None = None):
    """The implementation of op `name` for this frame: the numba kernel when
    ctx['backend'] is 'numba' (as resolved by the runner), else the torch reference."""
    ref_mod = KERNEL_OPS.get(name, "fgcli.ops")
    if ctx is not None and ctx.get("backend") == "numba" and name in KERNEL_OPS:
        from fgcli.kernels import ops as kops

        return getattr(kops, name)
    return getattr(importlib.import_module(ref_mod), name)
