"""The exactness contract of each kernel op against its torch reference, and the check that
the tests apply on every CPU.

torch picks its CPU kernels by the machine (AVX-512, AVX2, plain; other vector kernels
again on aarch64), and they round some float operations differently: a fused
multiply-add in one and a product rounded on its own in another (``lerp``, ``add(alpha=)``,
grid_sample's unnormalise), a vectorised ``pow`` against a scalar one. The kernels cannot
match all of them bit for bit, and need not: an op's contract says what must be equal and
how close its floats must be.

- **Decisions are exact**: bool and integer outputs (masks, holes, integer flow vectors,
  packed keys, winners' indices), the positions of NaN and +-inf in every float output,
  and, for ops whose contract has ``ulp == 0 and rel == 0``, every float value (tests that
  promise the sign of a zero compare bits themselves).
- **Float values** agree within ``ulp`` float32 units in the last place of the reference
  value, or within ``rel`` times the largest finite magnitude of the reference output's
  channel (the bound for values taken from interpolations and sums, whose error scales
  with the terms, not with the result).

A decision the reference takes on a float value may flip where that value lies within
the bound of the threshold; a test then excludes those elements (``unsure``) and says
why; everything else is compared.

Importing this module does not import torch or numba.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

EPS32 = 2.0 ** -23  # float32 machine epsilon (one ulp of 1.0)


@dataclass(frozen=True)
class Contract:
    """How a kernel op's outputs may differ from its reference (module docstring)."""

    ulp: int = 0  # float values within this many float32 ulps of the reference value ...
    rel: float = 0.0  # ... or within rel x the channel's largest finite |reference value|
    why: str = "the same float32 operations, each correctly rounded on every CPU"

    @property
    def exact(self) -> bool:
        return self.ulp == 0 and self.rel == 0.0


EXACT = Contract()
# lerp / add(alpha=): one product rounded inside an FMA or on its own
LERP = Contract(ulp=1, rel=EPS32,
                why="lerp's product is fused (FMA) by torch's vector kernels, rounded on its "
                    "own by its plain ones: 1 ulp of the larger operand")
# bilinear sampling (grid_sample's arithmetic): the sample position is rounded once more or
# less (FMA in the unnormalise), which moves every tap weight by a few ulp of a coordinate
# (< 2**-14 for the sizes up to 1024 px the tests use, relative to 1) times the spread of
# the taps (< 2x the channel's range), then lerps and sums of such values
BILINEAR = Contract(ulp=4, rel=2.0 ** -12,
                    why="bilinear tap weights from a sample position rounded with or without "
                        "FMA: a few ulp of a coordinate times the spread of the taps")
# pyramid fills: bilinear samples of box-average levels, summed over levels with FMA
# (add(alpha=)) and divided by the summed weight
PYRAMID = Contract(ulp=16, rel=2.0 ** -12,
                   why="bilinear samples of the levels (BILINEAR) summed with add(alpha=) "
                       "(FMA or not) and divided by the summed weight")
# a whole pipeline, numba against torch: its ops' bounds, carried through a few stages
PIPELINE = Contract(ulp=64, rel=2.0 ** -12,
                    why="the ops' BILINEAR / LERP differences carried through the later "
                        "stages (each a few roundings of the spread of its inputs)")

# every op of fgcli.kernels.KERNEL_OPS, and the kernel-level helpers the tests compare
CONTRACTS: dict[str, Contract] = {
    "dilate_nearest_depth": EXACT,
    # splat: the targets' positions are q + v * (alpha, alpha^2 terms) with FMA where torch
    # fuses; the winners (packed keys) are exact where a target is not within the bound of
    # a pixel boundary, the offsets within BILINEAR
    "splat_motion": BILINEAR,
    "gap_fill": BILINEAR,
    "fill_extrap_holes": BILINEAR,
    "blend_interp": LERP,
    "blend_eq1": LERP,
    "warp_frames": BILINEAR,
    "warp_blend": BILINEAR,
    "mv_warp": BILINEAR,
    "crossfade": LERP,
    "guiding_flows": BILINEAR,
    "block_flow": Contract(why="integer vectors from sums of 8-bit differences (exact in "
                               "float32 in any order)"),
    "vector_field": EXACT,
    "game_vector_field": EXACT,
    "reconstruct_depths": EXACT,
    "unproject": EXACT,
    "project": EXACT,
    "track_history": EXACT,
    "dilate_trajectory": EXACT,
    "dilated_positions": EXACT,
    "warp_positions": BILINEAR,
    "collect_background": EXACT,
    "project_background": EXACT,
    "background_fill": BILINEAR,
    "project_border": EXACT,
    "reproject_fill": BILINEAR,
    "fill_holes": PYRAMID,
    "push_pull_fill": PYRAMID,
    "vector_rule_fill": BILINEAR,
    "median_depth": EXACT,
    "disocclusion_masks": Contract(
        ulp=4, rel=2.0 ** -12,
        why="bilinear depth taps (BILINEAR); the masks' 0 / 1 decisions compared exactly"),
    "interpolate_fsr3": BILINEAR,
    "fill_packed_field": PYRAMID,
    "inpaint_color": PYRAMID,
    "pyramid_inpaint": PYRAMID,
    "luma8": EXACT,
    "luma8_u8": EXACT,
    "luma8_u8_of": EXACT,
    "depth_priority": EXACT,
    "avg_pool2": EXACT,
    "sample_flow_field": BILINEAR,
    "interpolated_depth": EXACT,
    "output_vectors": EXACT,
    "field_luminance": EXACT,
    "scene_change_score_tensor": EXACT,
}


def ulp_distance(a, b):
    """|a - b| in float32 ulps (int64 tensor; +0.0 and -0.0 are 0 apart)."""
    import torch

    def ordered(x):
        i = x.contiguous().view(torch.int32).to(torch.int64)
        return torch.where(i < 0, -(i & 0x7FFFFFFF), i)

    return (ordered(a) - ordered(b)).abs()


def check(name: str, got, want, contract: Contract, unsure=None) -> None:
    """Assert that ``got`` (a kernel's output: a tensor, None, a tuple / list / dict of
    them, or an object with tensor fields such as SplatResult) agrees with ``want`` (the
    reference's) under ``contract``. ``unsure``: a bool tensor broadcastable to the float
    outputs (or None): elements a test excludes because the reference's own decision lies
    within the bound of its threshold there."""
    import torch

    if isinstance(want, torch.Tensor) or isinstance(got, torch.Tensor):
        _check_tensor(name, got, want, contract, unsure)
    elif want is None or got is None:
        assert got is None and want is None, f"{name}: {got!r} vs {want!r}"
    elif isinstance(want, dict):
        assert got.keys() == want.keys(), name
        for k in want:
            check(f"{name}.{k}", got[k], want[k], contract, unsure)
    elif isinstance(want, (tuple, list)):
        assert len(got) == len(want), name
        for i, (x, y) in enumerate(zip(got, want)):
            check(f"{name}[{i}]", x, y, contract, unsure)
    elif dataclasses.is_dataclass(want):
        assert type(got) is type(want), name
        for f in dataclasses.fields(want):
            if f.compare:  # (compare=False: bookkeeping such as SplatResult.scratch)
                check(f"{name}.{f.name}", getattr(got, f.name), getattr(want, f.name),
                      contract, unsure)
    else:
        assert got == want, f"{name}: {got!r} vs {want!r}"


def _check_tensor(name, a, b, contract, unsure):
    import torch

    assert isinstance(a, torch.Tensor) and isinstance(b, torch.Tensor), name
    assert a.shape == b.shape and a.dtype == b.dtype, (name, a.shape, b.shape, a.dtype, b.dtype)
    if not a.dtype.is_floating_point:
        bad = a != b
        assert not bool(bad.any()), f"{name}: {int(bad.sum())} of {bad.numel()} differ (exact)"
        return
    a32, b32 = a.float(), b.float()
    skip = None
    if unsure is not None:
        skip = torch.broadcast_to(unsure.to(a.device), a.shape)
    # NaN and +-inf where the reference has them
    cls_a = torch.where(a32.isnan(), 3, torch.where(a32.isinf(), 1 + (a32 > 0).int(), 0))
    cls_b = torch.where(b32.isnan(), 3, torch.where(b32.isinf(), 1 + (b32 > 0).int(), 0))
    bad = cls_a != cls_b
    if contract.exact or a.dtype != torch.float32:
        bad |= (a != b) & ~(a.isnan() & b.isnan())  # (-0.0 == 0.0; NaN payloads not compared)
        what = "exactly"
    else:
        fin = cls_b == 0
        diff = (a32 - b32).abs()
        ok = ulp_distance(a32, b32) <= contract.ulp
        if contract.rel > 0.0:
            scale = torch.where(fin, b32.abs(), torch.zeros_like(b32))
            if scale.dim() >= 3:  # (C, H, W) or (B, C, H, W): per channel
                scale = scale.flatten(-2).amax(-1)[..., None, None]
            else:
                scale = scale.amax()
            ok |= diff <= contract.rel * scale
        bad |= fin & ~ok
        what = f"within {contract.ulp} ulp / {contract.rel:.3g} of the channel's range"
    if skip is not None:
        bad &= ~skip
    n = int(bad.sum())
    if n:
        i = int(bad.view(-1).nonzero()[0])
        raise AssertionError(f"{name}: {n} of {bad.numel()} elements differ beyond the "
                             f"contract ({what}), first at flat index {i}: kernel "
                             f"{a.reshape(-1)[i].item()!r}, reference {b.reshape(-1)[i].item()!r}")
