"""Shared helpers for the pure tensor ops: input checks, pixel grids, sanitising, batching.

Conventions (docs/design.md section 2): torch float32, channel-first. A per-frame tensor is
(C, H, W); a batch is (B, C, H, W). Pixel centres sit at integer + 0.5 in *pixel
coordinates*; inside the ops we work in *index coordinates* (pixel centre of column x is
x), which differ by a constant 0.5 and so leave every displacement unchanged.
"""
from __future__ import annotations

import functools
import math

import torch

# Finite stand-in for +-inf in filtered (interpolating) samplers: large enough to stay
# "infinitely far" for depth tests, small enough that a convex combination of 4 or 16
# such values cannot overflow float32.
BIG = 1.0e30
# Motion vectors are clamped to +-MV_MAX pixels: "off-screen" for any real image, and
# far from float32 overflow when scaled by the motion-model coefficients.
MV_MAX = 1.0e6
# Largest extrapolation distance accepted (in frame intervals): keeps alpha^2 * MV_MAX far
# from float32 overflow.
ALPHA_MAX = 1.0e6
# float32 bit pattern of +inf: the largest key a non-negative depth can produce.
INF_BITS = 0x7F800000


def check_tensor(x, name: str, channels: int | None = None, *, allow_batch: bool = True,
                 dtype_kind: str = "float") -> torch.Tensor:
    """Validate an image-like tensor and return it (float32 or bool, unchanged otherwise).

    Accepts (C, H, W) and, when allow_batch, (B, C, H, W). Raises TypeError for a
    non-tensor and ValueError (naming the argument and the shape) for a wrong rank,
    channel count or an empty spatial size.
    """
    if not isinstance(x, torch.Tensor):
        raise TypeError(f"{name}: expected a torch.Tensor, got {type(x).__name__}")
    ranks = (3, 4) if allow_batch else (3,)
    if x.dim() not in ranks:
        want = "(C, H, W) or (B, C, H, W)" if allow_batch else "(C, H, W)"
        raise ValueError(f"{name}: expected a {want} tensor, got shape {tuple(x.shape)}")
    if channels is not None and x.shape[-3] != channels:
        raise ValueError(f"{name}: expected {channels} channel(s) in dim -3, "
                         f"got shape {tuple(x.shape)}")
    if x.shape[-1] == 0 or x.shape[-2] == 0 or (x.dim() == 4 and x.shape[0] == 0):
        raise ValueError(f"{name}: empty tensor, shape {tuple(x.shape)}")
    if dtype_kind == "float":
        if x.dtype == torch.bool or not (x.is_floating_point() or x.dtype in
                                         (torch.int32, torch.int64, torch.uint8, torch.int16)):
            raise TypeError(f"{name}: expected a float tensor, got {x.dtype}")
        if x.dtype != torch.float32:
            x = x.float()
    elif dtype_kind == "bool":
        if x.dtype != torch.bool:
            raise TypeError(f"{name}: expected a bool tensor, got {x.dtype}")
    return x


def check_same(ref: torch.Tensor, ref_name: str, *others) -> None:
    """Check that (tensor, name) pairs share rank, batch size and (H, W) with ref."""
    for t, name in others:
        if t is None:
            continue
        if t.dim() != ref.dim():
            raise ValueError(f"{name}: rank {t.dim()} (shape {tuple(t.shape)}) does not match "
                             f"{ref_name} shape {tuple(ref.shape)}; batch all inputs or none")
        if t.shape[-2:] != ref.shape[-2:]:
            raise ValueError(f"{name}: size {tuple(t.shape[-2:])} does not match {ref_name} "
                             f"size {tuple(ref.shape[-2:])}")
        if t.dim() == 4 and t.shape[0] != ref.shape[0]:
            raise ValueError(f"{name}: batch {t.shape[0]} does not match {ref_name} "
                             f"batch {ref.shape[0]}")


def check_alpha(alpha, name: str = "alpha", lo: float = 0.0, hi: float | None = 1.0) -> float:
    try:
        a = float(alpha)
    except (TypeError, ValueError):
        raise TypeError(f"{name}: expected a number, got {type(alpha).__name__}") from None
    if not math.isfinite(a) or a < lo or (hi is not None and a > hi):
        rng = f"[{lo}, {hi}]" if hi is not None else f">= {lo}"
        raise ValueError(f"{name}: must be finite and in {rng}, got {alpha!r}")
    return a


def check_choice(value, name: str, choices) -> str:
    if value not in choices:
        raise ValueError(f"{name}: expected one of {sorted(choices)}, got {value!r}")
    return value


@functools.lru_cache(maxsize=16)
def _grid_cached(h: int, w: int, device: str):
    dev = torch.device(device)
    gx = torch.arange(w, dtype=torch.float32, device=dev).expand(h, w)
    gy = torch.arange(h, dtype=torch.float32, device=dev)[:, None].expand(h, w)
    return gx, gy


def grid(h: int, w: int, device) -> tuple[torch.Tensor, torch.Tensor]:
    """Index-coordinate grids (H, W) (expanded views, do not write into them)."""
    return _grid_cached(int(h), int(w), str(device))


@functools.lru_cache(maxsize=16)
def _aux_cached(h: int, w: int, device: str):
    dev = torch.device(device)
    xs = torch.arange(w, dtype=torch.float32, device=dev)
    ys = torch.arange(h, dtype=torch.float32, device=dev)
    return {
        # x + 0.5 as a row / column (broadcast): nearest pixel = floor(x + 0.5 + flow)
        "xh": xs + 0.5, "yh": (ys + 0.5)[:, None],
        # grid_sample (align_corners=False) normalised pixel centres, contiguous (H, W)
        "gxn": ((xs + 0.5) * (2.0 / w) - 1.0).expand(h, w).contiguous(),
        "gyn": ((ys + 0.5) * (2.0 / h) - 1.0)[:, None].expand(h, w).contiguous(),
        # inside-the-image thresholds on the flow itself: -0.5 - x <= f < w - 0.5 - x
        "lox": -0.5 - xs, "hix": (w - 0.5) - xs,
        "loy": (-0.5 - ys)[:, None], "hiy": ((h - 0.5) - ys)[:, None],
        "ar64": torch.arange(h * w, dtype=torch.int64, device=dev),
        "ar32": torch.arange(h * w, dtype=torch.int32, device=dev),
    }


def aux(h: int, w: int, device) -> dict:
    """Cached per-size helper tensors (read-only)."""
    return _aux_cached(int(h), int(w), str(device))


# float32 integer arithmetic is exact below 2**24: flat indices of images up to 16.7 Mpx
EXACT_F32 = 1 << 24


def reads_back(t: torch.Tensor) -> bool:
    """Whether a data-dependent shortcut may read a value of ``t`` back to Python.

    On the CPU a reduction read back is cheap and lets an op skip work it does not need
    (a sanitising copy of clean data, a hole pass without holes). On a GPU every such read
    is a host round-trip that stalls the stream, so there the ops take their dense,
    branch-free path instead, which gives the same values (issue 9: no host round-trips
    inside a pipeline; `benchmarks/stages.py --device cuda --sync-report` counts them).
    ``FORCE_DENSE`` makes the CPU take that path too (tests compare the two)."""
    return t.device.type == "cpu" and not FORCE_DENSE


# tests set this to run the GPU (dense, no read-back) paths on the CPU
FORCE_DENSE = False


# ----------------------------------------------------------------------------- scratch
# A frame's intermediate planes (the warped frame of gffe-extrap, say) pass from stage to
# stage; each hole stage used to copy all of them to change the few hole pixels. An op
# that makes fresh planes (no one else holds them) marks them scratch; an op called with
# in_place=True may then write into its inputs, where every one it would write is marked,
# instead of copying them (the caller gives its references up). The mark is an attribute
# of the tensor object: a view or any other tensor made from it is unmarked, and
# ``unmarked`` gives an alias without the mark (fgcli.pipeline's measuring runs of
# skipped stages). Inputs read from files are never marked.

SCRATCH_ATTR = "_fgen_scratch"


def mark_scratch(*ts):
    """Mark fresh tensors, which no one else holds yet, as scratch; returns them."""
    for t in ts:
        setattr(t, SCRATCH_ATTR, True)
    return ts[0] if len(ts) == 1 else ts


def is_scratch(*ts) -> bool:
    """Whether every one of ts is a tensor marked scratch (mark_scratch)."""
    return all(isinstance(t, torch.Tensor) and t.__dict__.get(SCRATCH_ATTR, False) is True
               for t in ts)


def unmarked(t):
    """t itself, or where it is marked scratch an alias of it (same storage) without the
    mark, so that an in-place op leaves it alone."""
    return t.view_as(t) if is_scratch(t) else t


def all_set(mask: torch.Tensor) -> bool:
    """bool(mask.all()), read back. On the CPU numpy answers at the first False element;
    torch's reduction reads the whole mask (1.1 ms for a 1080p mask here, against
    0.01 ms when a hole comes early)."""
    if mask.device.type == "cpu" and mask.dtype == torch.bool:
        return bool(mask.numpy().all())
    return bool(mask.all())


def any_set(mask: torch.Tensor) -> bool:
    """bool(mask.any()), read back; early exit on the CPU as all_set."""
    if mask.device.type == "cpu" and mask.dtype == torch.bool:
        return bool(mask.numpy().any())
    return bool(mask.any())


def flow_is_clean(flow: torch.Tensor, limit: float = MV_MAX) -> bool:
    """True when every value is finite and within +-limit (two cheap reductions). Off the
    CPU (see reads_back) it answers False without looking: the caller sanitises."""
    if flow.numel() == 0:
        return True
    if not reads_back(flow):
        return False
    hi, lo = float(flow.amax()), float(flow.amin())  # NaN propagates -> False below
    return hi <= limit and lo >= -limit


def sanitize_flow_positions(flow: torch.Tensor) -> torch.Tensor:
    """Flow safe for index arithmetic: NaN -> far off-screen (so it reads as invalid),
    +-inf and huge values -> +-4e6 px (still off-screen). No copy when already clean."""
    if flow_is_clean(flow):
        return flow
    far = 4.0 * MV_MAX
    return torch.nan_to_num(flow, nan=-far, posinf=far, neginf=-far).clamp_(-far, far)


def inside_mask(flow: torch.Tensor, h: int, w: int) -> torch.Tensor:
    """(H, W) bool: the position xy + flow lies in the image rectangle [0, W) x [0, H)
    (pixel coordinates), tested on the flow against exact per-column/row thresholds.
    NaN flow gives False."""
    a = aux(h, w, flow.device)
    vx = (flow[0] >= a["lox"]) & (flow[0] < a["hix"])
    vy = (flow[1] >= a["loy"]) & (flow[1] < a["hiy"])
    return vx.logical_and_(vy)


def nearest_index(flow: torch.Tensor, h: int, w: int) -> torch.Tensor:
    """Flat index (N,) int32 (int64 above 2**31 px) of the pixel nearest ``xy + flow``,
    clamped to the image (edge replicate). ``flow`` must be finite (see
    sanitize_flow_positions); ties (exact half pixels) round up."""
    a = aux(h, w, flow.device)
    ix = torch.add(flow[0], a["xh"]).floor_().clamp_(0, w - 1)
    iy = torch.add(flow[1], a["yh"]).floor_().clamp_(0, h - 1)
    if h * w < EXACT_F32:
        return iy.mul_(w).add_(ix).view(-1).to(torch.int32)
    idx = iy.to(torch.int64).mul_(w).add_(ix.to(torch.int64)).view(-1)
    return idx if h * w >= 2 ** 31 else idx.to(torch.int32)


def gather_pixels(field: torch.Tensor, idx: torch.Tensor, out: torch.Tensor | None = None):
    """field (C, H, W) read at flat indices idx (M,) -> (C, M) (per-channel index_select,
    the fastest CPU gather)."""
    c = field.shape[0]
    flat = field.reshape(c, -1)
    if out is None:
        out = torch.empty((c, idx.numel()), dtype=field.dtype, device=field.device)
    for k in range(c):
        torch.index_select(flat[k], 0, idx, out=out[k])
    return out


def sanitize_values(x: torch.Tensor, big: float = BIG) -> torch.Tensor:
    """NaN -> 0, +-inf -> +-big; returns x itself when it is already finite (no copy).

    The finiteness test sums the tensor (cheap) instead of isfinite().all() (slow on CPU):
    a finite sum proves every element finite; otherwise we sanitise (conservatively).
    """
    if x.numel() == 0 or (reads_back(x) and math.isfinite(float(x.sum()))):
        return x
    return torch.nan_to_num(x, nan=0.0, posinf=big, neginf=-big)


def sanitize_mv(mv: torch.Tensor) -> torch.Tensor:
    """Motion vectors with NaN -> 0 and components clamped to +-MV_MAX (no copy if clean)."""
    if mv.numel() == 0:
        return mv
    if reads_back(mv):
        hi, lo = float(mv.amax()), float(mv.amin())  # amax/amin propagate NaN
        if hi <= MV_MAX and lo >= -MV_MAX:
            return mv
    return torch.nan_to_num(mv, nan=0.0, posinf=MV_MAX, neginf=-MV_MAX).clamp_(-MV_MAX, MV_MAX)


def sanitize_depth(depth: torch.Tensor) -> torch.Tensor:
    """Depth with NaN -> +inf and negatives (incl. -0.0, -inf) -> +0 (no copy if clean)."""
    if depth.numel() == 0:
        return depth
    # False for NaN (amin propagates NaN) and for any <= 0
    if reads_back(depth) and float(depth.amin()) > 0.0:
        return depth
    d = torch.nan_to_num(depth, nan=float("inf"), posinf=float("inf"), neginf=0.0)
    return d.clamp_(min=0.0).abs_()  # abs_ turns -0.0 into +0.0


def per_frame(fn, batched: torch.Tensor, *args):
    """Apply fn(frame_i, *args_i) to each frame of a (B, ...) batch and stack the outputs.

    args may hold (B, ...) tensors (sliced per frame) or anything else (passed through).
    fn may return a tensor or a tuple of tensors.
    """
    outs = []
    for i in range(batched.shape[0]):
        a_i = [a[i] if isinstance(a, torch.Tensor) and a.dim() == 4 else a for a in args]
        outs.append(fn(batched[i], *a_i))
    if isinstance(outs[0], tuple):
        return tuple(torch.stack([o[k] for o in outs]) for k in range(len(outs[0])))
    return torch.stack(outs)


from fgcli.sysutil import tune_allocator  # noqa: E402,F401  pyflakes: ignore (re-export)

__all__ = ["tune_allocator"]
