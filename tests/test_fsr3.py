"""fsr3-interp (issue 10): each op (shapes, known answer, hard cases), the shared pyramid
inpainting op, the camera-cut splice, the loader's data-flow check, and the poor-vector
scene where the optical-flow bias must carry the result."""
from __future__ import annotations

import json
import math
import os

import pytest
import torch
from click.testing import CliRunner

from fgcli import pipeline as pl
from fgcli.cli import cli
from fgcli.errors import UsageError
from fgcli.frame import Frame
from fgcli.io.frames import read_frame, write_frame
from fgcli.io.reader import SequenceReader
from fgcli.kernels.contract import PIPELINE, check
from fgcli.ops import fsr3
from fgcli.ops.pyramid import pyramid_inpaint, weighted_pyramid
from fgcli.runner import make_ctx

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
INF = math.inf
NAN = math.nan


def _texture(h, w, seed=0):
    """Multi-scale noise (structure at every pyramid level), values in [0, 1]."""
    g = torch.Generator().manual_seed(seed)
    acc = torch.zeros(3, h, w)
    for s in (32, 16, 8, 4, 1):
        base = torch.rand(3, -(-h // s), -(-w // s), generator=g)
        acc += torch.nn.functional.interpolate(base[None], size=(h, w), mode="bilinear",
                                               align_corners=False)[0]
    return acc / 5


# ----------------------------------------------------------------------------- pyramid

def test_pyramid_shapes_and_constant_fill():
    v = torch.full((3, 13, 21), 0.25)
    w = torch.ones(1, 13, 21)
    w[:, 3:9, 5:15] = 0
    lev = weighted_pyramid(v, w)
    assert lev[0].shape == (4, 13, 21) and lev[-1].shape[-2:] == (1, 1)
    assert [tuple(t.shape[-2:]) for t in lev[:3]] == [(13, 21), (7, 11), (4, 6)]
    for mode in ("blend", "first"):
        out, filled = pyramid_inpaint(v.masked_fill(w == 0, 99.0), w, mode=mode)
        assert torch.allclose(out, v, atol=1e-6)  # holes never leak into the average
        assert filled.sum() == 6 * 10


def test_pyramid_known_answer_and_hard_cases():
    # left half 0, right half 1, a hole in the middle column takes something in between
    v = torch.zeros(1, 8, 8)
    v[:, :, 4:] = 1.0
    w = torch.ones(1, 8, 8)
    w[:, :, 3:5] = 0
    out, _ = pyramid_inpaint(v, w, mode="first")
    assert 0.0 < out[0, 4, 3] < out[0, 4, 4] < 1.0
    # no data at all: zeros, nothing filled; 1x1; NaN/Inf values
    out, filled = pyramid_inpaint(torch.ones(2, 5, 3), torch.zeros(1, 5, 3))
    assert not out.any() and not filled.any()
    out, filled = pyramid_inpaint(torch.ones(2, 1, 1), torch.zeros(1, 1, 1))
    assert out.shape == (2, 1, 1) and not filled.any()
    bad = torch.tensor([[[float("nan"), INF], [1.0, -INF]]])
    out, _ = pyramid_inpaint(bad, torch.tensor([[[0.0, 1.0], [1.0, float("nan")]]]))
    assert torch.isfinite(out).all()
    with pytest.raises(ValueError):
        pyramid_inpaint(torch.ones(3, 4, 4), torch.ones(1, 4, 5))
    with pytest.raises(ValueError):
        pyramid_inpaint(torch.ones(3, 4, 4), torch.ones(1, 4, 4), mode="nope")


# ----------------------------------------------------------------------------- depth

def test_reconstruct_depths_known_shift_and_zero_motion():
    d = torch.full((1, 6, 9), 10.0)
    d[0, 2, 2] = 1.0
    mv = torch.zeros(2, 6, 9)
    mv[0, 2, 2] = 4.0  # that surface was 4 px to the right in frame 0
    prev, mid = fsr3.reconstruct_depths(d, mv, 0.5)
    assert prev.shape == mid.shape == (1, 6, 9)
    assert prev[0, 2, 6] == 1.0 and mid[0, 2, 4] == 1.0  # atomic min: nearest wins
    assert prev[0, 2, 2] == INF  # nothing landed where it left (the bilinear footprint only)
    p0, m0 = fsr3.reconstruct_depths(d, torch.full((2, 6, 9), 0.05), 0.3)  # < 0.1 px: zeroed
    assert torch.equal(p0, d) and torch.equal(m0, d)


@pytest.mark.parametrize("h,w", [(1, 1), (1, 7), (5, 1), (7, 5)])
def test_reconstruct_depths_hard_cases(h, w):
    for d in (torch.zeros(1, h, w), torch.full((1, h, w), INF),
              torch.full((1, h, w), float("nan"))):
        for mv in (torch.full((2, h, w), 1e7), torch.full((2, h, w), float("nan")),
                   torch.zeros(2, h, w)):
            a, b = fsr3.reconstruct_depths(d, mv, 1.0)
            assert not torch.isnan(a).any() and not torch.isnan(b).any()
            assert (a >= 0).all()


# ----------------------------------------------------------------------------- vector field

def test_priorities_and_packing_roundtrip():
    hi = fsr3.depth_priority(torch.tensor([[[0.0, 1.0, 100.0, INF, float("nan")]]]))
    assert hi[0, 0, 0] == 1023 and hi[0, 0, 3] == 1 and hi[0, 0, 4] == 1
    assert hi[0, 0, 1] > hi[0, 0, 2]  # near is better
    assert fsr3.agreement_priority(torch.tensor(1.0), torch.tensor(1.0)) == 31
    assert fsr3.agreement_priority(torch.tensor(0.0), torch.tensor(10.0)) == 0
    comp = torch.tensor([[[-3.5, 0.0, 12.25, 1e9]]])
    packed = torch.cat([fsr3.pack_entries(True, torch.full_like(comp, 7, dtype=torch.int64),
                                          torch.full_like(comp, 3, dtype=torch.int64), comp)] * 2)
    vec, prio, valid = fsr3.unpack_vector_field(packed)
    assert valid.all() and (prio == (1 << 15 | 7 << 5 | 3)).all()
    assert vec[0, 0].tolist() == [-3.5, 0.0, 12.25, 65504.0]
    # primary beats secondary beats nothing, whatever the depth priority
    a = fsr3.pack_entries(True, torch.tensor(1), torch.tensor(0), torch.tensor(1.0))
    b = fsr3.pack_entries(False, torch.tensor(1023), torch.tensor(31), torch.tensor(1.0))
    assert a > b > 0


def test_vector_field_uniform_motion_and_secondary():
    h, w = 12, 16
    c = _texture(h, w)
    mv = torch.zeros(2, h, w)
    mv[0] = 4.0
    hi = fsr3.depth_priority(torch.full((1, h, w), 5.0))
    field = fsr3.vector_field(c, c, mv, hi, 0.5)
    vec, prio, valid = fsr3.unpack_vector_field(field)
    assert vec.shape == (2, h, w)
    # every pixel moved 2 px right at t = 0.5: columns 2.. are written with the vector
    assert valid[:, :, 2:].all() and (vec[0, :, 2:] == 4.0).all()
    # a small object moving over static ground: secondary entries fill behind it
    mv2 = torch.zeros(2, h, w)
    mv2[0, 4:6, 4:6] = -8.0
    d = torch.full((1, h, w), 10.0)
    d[:, 4:6, 4:6] = 1.0
    f1 = fsr3.vector_field(c, c, mv2, fsr3.depth_priority(d), 0.5, secondary=True)
    f0 = fsr3.vector_field(c, c, mv2, fsr3.depth_priority(d), 0.5, secondary=False)
    assert (f1 >= f0).all() and (f1 != f0).any()
    filled, _ = fsr3.fill_vector_field(*fsr3.unpack_vector_field(f0))
    assert torch.isfinite(filled).all()


# ----------------------------------------------------------------------------- optical flow

def test_block_flow_recovers_a_shift():
    h, w = 64, 96
    c0 = _texture(h + 16, w + 16, 3)
    img0 = c0[:, 8:8 + h, 8:8 + w]
    img1 = c0[:, 8 + 2:8 + 2 + h, 8 - 5:8 - 5 + w]  # frame 1 at x shows frame 0 at x - 5, y + 2
    f = fsr3.block_flow(fsr3.luma8(img0), fsr3.luma8(img1))
    assert f.shape == (2, 8, 12)
    inner = f[:, 1:-1, 1:-1]
    assert (inner[0] == -5).float().mean() > 0.9 and (inner[1] == 2).float().mean() > 0.9
    # identical frames: zero flow (ties go to zero offset); tiny and flat images
    assert not fsr3.block_flow(fsr3.luma8(img0), fsr3.luma8(img0)).any()
    assert fsr3.block_flow(torch.zeros(1, 1, 1), torch.zeros(1, 1, 1)).shape == (2, 1, 1)
    up = fsr3.upsample_block_flow(f, h, w)
    assert up.shape == (2, h, w)


def test_vector_median_removes_an_outlier():
    f = torch.ones(2, 5, 5)
    f[:, 2, 2] = 40.0
    out = fsr3._vector_median3(f)
    assert torch.equal(out, torch.ones(2, 5, 5))


def test_smooth_block_flow_votes_down_an_outlier_and_keeps_uniform_motion():
    f = torch.zeros(2, 7, 9)
    f[0] = 6.0
    f[1] = -2.0
    s = fsr3.smooth_block_flow(f)
    assert torch.allclose(s, f, atol=1e-5)  # uniform motion stays
    g = f.clone()
    g[:, 3, 4] = torch.tensor([-6.0, 2.0])  # opposes all its neighbours: no weight
    s = fsr3.smooth_block_flow(g)
    assert torch.allclose(s[:, 3, 4], f[:, 3, 4], atol=1e-4)
    # vectors of 1 px or less and over 512 px have no weight; none moving -> zero
    z = torch.full((2, 4, 4), 0.5)
    assert torch.equal(fsr3.smooth_block_flow(z), torch.zeros(2, 4, 4))
    h = torch.tensor([[[NAN, INF, -INF, 3.0]], [[1.0, 2.0, 3.0, 4.0]]])
    assert bool(torch.isfinite(fsr3.smooth_block_flow(h)).all())


@pytest.mark.parametrize("smooth", [True, False])
def test_flow_vector_field_on_the_block_grid(smooth):
    """field=block (the FidelityFX SDK's optical-flow field): a uniform block flow of
    (16, -8) px lands on the texels (1 - alpha) v / 8 away, the priority is the SDK's
    magnitude rule, the sampled per-pixel vectors are the flow where the field is written;
    short vectors (<= 1 px) write nothing; hard cases stay finite."""
    h, w = 64, 96
    c1 = _texture(h, w, 3)
    c0 = torch.roll(c1, shifts=(-8, 16), dims=(1, 2))  # frame 1 at p shows frame 0 at p + v
    f = torch.zeros(2, 8, 12)
    f[0], f[1] = 16.0, -8.0
    field = fsr3.flow_vector_field(c0, c1, f, 0.5, 8, smooth=smooth)
    assert field.shape == (2, 8, 12)
    vec, prio, valid = fsr3.unpack_vector_field(field)
    # sources move by (1, -0.5) texels: rows 0..6 written from below, row 7 only by its
    # own source's lower tap (none), column 0 by no source
    assert bool(valid[0, :7, 1:].all()) and not bool(valid[0, :, 0].any())
    vel = math.hypot(16.0, 8.0)
    hi = int(min(vel / (0.05 * math.hypot(w, h)), 1.0) * 1023)
    assert int(((prio >> 5) & 1023)[valid].max()) == hi
    assert torch.equal(vec[0][valid[0]], torch.full((int(valid.sum()),), 16.0))
    lo = (prio & 31)[valid]  # the rolled frames agree: 31, or 0 where p + v is off-screen
    assert bool(((lo == 31) | (lo == 0)).all()) and float((lo == 31).float().mean()) > 0.7
    of = fsr3.sample_flow_field(field, h, w, 8)
    assert of.shape == (2, h, w)
    assert torch.equal(of[:, 8:48, 16:], torch.stack([torch.full((40, 80), 16.0),
                                                        torch.full((40, 80), -8.0)]))
    # 1 px or less: no entries, zero vectors
    small = torch.full((2, 8, 12), 0.6)
    assert int(fsr3.flow_vector_field(c0, c1, small, 0.5, 8, smooth=smooth).abs().sum()) == 0
    # hard cases
    bad = f.clone()
    bad[0, 2, 3], bad[1, 4, 5], bad[0, 0, 0] = NAN, INF, -1e9
    cb = c1.clone()
    cb[:, 10, 10], cb[:, 20, 20] = NAN, INF
    fb = fsr3.flow_vector_field(cb, cb, bad, 0.25, 8, smooth=smooth)
    assert bool(torch.isfinite(fsr3.sample_flow_field(fb, h, w, 8)).all())
    with pytest.raises(ValueError, match="flow: expected"):
        fsr3.flow_vector_field(c0, c1, torch.zeros(2, 8, 11), 0.5, 8)


def test_dis_flow_shapes_and_shift():
    h, w = 64, 96
    c0 = _texture(h + 16, w + 16, 4)
    img0 = c0[:, 8:8 + h, 8:8 + w]
    img1 = c0[:, 8:8 + h, 8 - 3:8 - 3 + w]
    f = fsr3.dis_flow(fsr3.luma8(img0), fsr3.luma8(img1))
    assert f.shape == (2, h, w)
    assert abs(float(f[0, 16:-16, 16:-16].median()) + 3.0) < 0.5
    assert fsr3.dis_flow(torch.zeros(1, 1, 3), torch.zeros(1, 1, 3)).shape == (2, 1, 3)


# ----------------------------------------------------------------------------- masks, interp

def test_disocclusion_masks_known_answer():
    h, w = 8, 12
    d = torch.full((1, h, w), 10.0)
    z = torch.zeros(2, h, w)
    mp, mc = fsr3.disocclusion_masks(d, d, d, z, 0.5, 1.4)
    assert mp.shape == mc.shape == (1, h, w) and mp.all() and mc.all()
    # the previous frame had a nearer surface where this pixel's surface now shows
    dp = d.clone()
    dp[:, 3, 3] = 1.0
    mp, mc = fsr3.disocclusion_masks(d, dp, d, z, 0.5, 1.4)
    assert mp[0, 3, 3] == 0 and mc[0, 3, 3] == 1
    # farther at the source is not an occluder (one-sided); sky vs sky is the same surface
    far = d.clone()
    far[:, 3, 3] = 100.0
    assert fsr3.disocclusion_masks(d, far, d, z)[0].all()
    sky = torch.full((1, h, w), INF)
    assert fsr3.disocclusion_masks(sky, sky, sky, z)[0].all()
    assert fsr3.camera_kfov(None, 16, 9, 60.0) > 1.0


def test_interpolate_zero_motion_is_exact_and_bias_prefers_the_better_pair():
    h, w = 10, 14
    c = _texture(h, w)
    z = torch.zeros(2, h, w)
    one = torch.ones(1, h, w)
    out, holes, bias = fsr3.interpolate_fsr3(c, c, z, one, one, 0.37, of_vec=z)
    assert torch.equal(out, c) and not holes.any() and (bias == 1).all()
    # content moved 4 px left; the game vectors are wrong (zero), the flow is right
    big = _texture(h, w + 8, 5)
    c0, c1 = big[:, :, 4:4 + w], big[:, :, 0:w]  # frame 1 at x shows frame 0 at x - 4 ...
    of = torch.zeros(2, h, w)
    of[0] = -4.0
    gt = big[:, :, 2:2 + w]
    out, _, bias = fsr3.interpolate_fsr3(c0, c1, z, one, one, 0.5, of_vec=of)
    game_only, _, _ = fsr3.interpolate_fsr3(c0, c1, z, one, one, 0.5)
    inner = (slice(None), slice(None), slice(3, -3))
    # bias = clamp(S_game / S_of, 0, 1) leans toward the flow pair by how much better it
    # matches (RGB-direction similarity: a partial mix on this low-saturation texture)
    assert (out - gt)[inner].abs().mean() < 0.95 * (game_only - gt)[inner].abs().mean()
    assert bias.mean() < 0.99
    # both masks 0: a hole; similarity known answers
    zero = torch.zeros(1, h, w)
    assert fsr3.interpolate_fsr3(c, c, z, zero, zero, 0.5)[1].all()
    s = fsr3.color_similarity(torch.tensor([[[1.0]], [[0.0]], [[0.0]]]),
                              torch.tensor([[[0.0]], [[1.0]], [[0.0]]]))
    assert s.item() == 0.0
    assert fsr3.color_similarity(torch.zeros(3, 1, 1), torch.zeros(3, 1, 1)).item() == 1.0


def test_inpaint_color_fills_holes_only():
    c = _texture(9, 11)
    holes = torch.zeros(1, 9, 11, dtype=torch.bool)
    holes[:, 4, 5] = True
    out = fsr3.inpaint_color(c, holes)
    assert torch.equal(out[:, ~holes[0]], c[:, ~holes[0]])
    assert torch.isfinite(out).all() and not torch.equal(out[:, 4, 5], c[:, 4, 5])


# ----------------------------------------------------------------------------- pipeline

def test_variants_and_flow_description():
    p = pl.load("fsr3-interp:optical_flow=off")
    assert "optical_flow" not in [s.id for s, _ in p.build("interp")]
    pl.load("fsr3-interp:flow=dis").build("interp")
    d = pl.describe(pl.load("fsr3-interp"))
    rows = {r["id"]: dict(r["inputs"]) for r in d["flow"]["interp"]}
    assert rows["fsr3_interpolate"]["game_mv"] == "fsr3_field_fill"
    assert rows["fsr3_interpolate"]["of_mv"] == "optical_flow"
    r = CliRunner().invoke(cli, ["describe", "fsr3-interp"])
    assert r.exit_code == 0 and "data flow (interp)" in r.output


def test_loader_rejects_a_broken_data_flow(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('name = "bad"\nmodes = ["interp"]\n\n[[stage]]\nuse = "dilate"\n\n'
                   '[[stage]]\nuse = "fsr3_field_fill"\n\n[[stage]]\nuse = "crossfade"\n')
    with pytest.raises(UsageError) as e:
        pl.load(str(bad))
    msg = str(e.value)
    assert "bad.toml:7" in msg and "fsr3_field_fill" in msg and "game_field" in msg
    # a stage switched off by a variant is caught too (its consumer loses its input)
    with pytest.raises(UsageError, match="depth1_d"):
        pl.load("fsr3-interp:dilate=off")
    nothing = tmp_path / "nothing.toml"
    nothing.write_text('name = "nothing"\nmodes = ["interp"]\n\n[[stage]]\nuse = "dilate"\n')
    with pytest.raises(UsageError, match="produces no color"):
        pl.load(str(nothing))


def test_every_bundled_pipeline_passes_the_flow_check():
    for name in pl.available():
        p = pl.load(name)
        for m in p.modes:
            pl.check_flow(p, m, p.build(m))


def _frames(scene, n):
    r = SequenceReader(os.path.join(ROOT, "sample_data", scene, "input"))
    return [r.read(k) for k in r.numbers[:n]]


def test_camera_cut_splice_is_never_blended(tmp_path):
    a = _frames("orbit", 2)
    b = _frames("throw", 2)
    seq = tmp_path / "splice"
    os.makedirs(seq)
    for i, f in enumerate(a + b):
        write_frame(str(seq / f"s.{i:04d}.exr"),
                    Frame(number=i, color=f.color, depth=f.depth, mv=f.mv, camera=f.camera))
    out = tmp_path / "out"
    r = CliRunner().invoke(cli, ["interpolate", str(seq), str(out), "--pipeline", "fsr3-interp",
                                 "--no-progress"])
    assert r.exit_code == 0, r.output
    run = json.loads((out / "fgen-run.json").read_text())
    cut_frames = {s["frame"] for s in run["skipped_stages"] if "scene cut" in s["why"]}
    assert cut_frames == {"3"}  # between input 1 (orbit) and 2 (throw)
    if "scene_cuts" in run:
        assert run["scene_cuts"]["cuts"] in (["3"], [3])
    got = read_frame(str(out / "s.0003.exr"), 3)
    assert torch.equal(got.color, a[1].color.half().float()) or torch.equal(
        got.color, b[0].color.half().float())
    # away from the cut the frames are generated (not copies)
    g1 = read_frame(str(out / "s.0001.exr"), 1)
    assert not torch.equal(g1.color, a[0].color.half().float())


def test_zero_motion_stages_are_skipped_exactly():
    f = _frames("shadows", 2)
    p = pl.load("fsr3-interp")
    tm = pl.Timings()
    ctx = pl.run_stages(p.build("interp"), make_ctx(f[0], f[1], 0.5, "interp"), tm, label="1")
    skipped = {s for _, s, _ in tm.skipped}
    assert {"fsr3_depth", "fsr3_game_field", "fsr3_disocclusion"} <= skipped
    assert torch.isfinite(ctx["color"]).all()


@pytest.mark.slow
def test_poor_vectors_scene_flow_bias_carries(tmp_path):
    """sample_data/scenes/spinner.toml (rendered here, 3 input frames): a fast-spinning
    ball whose texture scrolls and whose highlight stays with the light; the optical-flow
    bias must put fsr3-interp above blend and mob-fgsr."""
    from fgcli.synth import load_scene, render_sequence

    sc = load_scene(os.path.join(ROOT, "sample_data", "scenes", "spinner.toml"), frames=3)
    render_sequence(sc, str(tmp_path / "in"), gt_dir=str(tmp_path / "gt"), gt_factor=2,
                    progress=False)
    js = tmp_path / "r.json"
    r = CliRunner().invoke(cli, ["eval", str(tmp_path / "in"), "--gt", str(tmp_path / "gt"),
                                 "--pipeline", "fsr3-interp,mob-fgsr,blend",
                                 "--variant", "fsr3-interp:optical_flow=off", "--json", str(js),
                                 "--no-progress", "--no-hdr-flip"])
    assert r.exit_code == 0, r.output
    res = json.loads(js.read_text())["pipelines"]
    f = res["fsr3-interp"]["psnr"]
    assert f > res["blend"]["psnr"] + 1.0 and f > res["mob-fgsr"]["psnr"] + 1.0
    assert f > res["fsr3-interp:optical_flow=off"]["psnr"]


def _forward_only(src, dst):
    """Rewrite an fgen-layout sequence with forward vectors only (Nuke-style forward.u/v, no
    backward.u/v): frame t's forward vectors are frame t+1's backward vectors splatted into
    frame t with a depth test (fgcli.io.derive.backward_from_forward read the other way);
    the last frame's are zero (never used for interpolation). Reading the result, fgen
    derives each frame's backward vectors from the previous frame's forward vectors."""
    from fgcli.io.derive import backward_from_forward

    r = SequenceReader(str(src))
    frames = [r.read(n) for n in r.numbers]
    os.makedirs(dst, exist_ok=True)
    for k, f in enumerate(frames):
        if k + 1 < len(frames):
            nxt = frames[k + 1]
            fwd, _ = backward_from_forward(nxt.mv.numpy(), nxt.depth.numpy())
            fwd = torch.from_numpy(fwd)
        else:
            fwd = torch.zeros(2, f.height, f.width)
        write_frame(os.path.join(str(dst), f"s.{f.number:04d}.exr"),
                    Frame(number=f.number, color=f.color, depth=f.depth, mv_fwd=fwd,
                          camera=f.camera), layout="nuke")


@pytest.mark.slow
def test_forward_only_vectors_flow_bias_carries(tmp_path):
    """The spinner scene (256x144, 9 input frames) rewritten with forward vectors only: the
    backward vectors fgen derives from them are poor on top of describing the spin only;
    the game/optical-flow similarity bias must carry fsr3-interp more than 1 dB above blend
    and mob-fgsr. Slow: at 128x72 the stripes alias and blend wins (42.5 dB vs 38.0), and
    with 3-5 frames at 256x144 the margin over blend is only 0.8-0.9 dB."""
    from fgcli.synth import load_scene, render_sequence

    sc = load_scene(os.path.join(ROOT, "sample_data", "scenes", "spinner.toml"))
    render_sequence(sc, str(tmp_path / "in"), gt_dir=str(tmp_path / "gt"), gt_factor=2,
                    progress=False)
    _forward_only(tmp_path / "in", tmp_path / "fwd")
    r = CliRunner().invoke(cli, ["info", str(tmp_path / "fwd")])
    assert r.exit_code == 0 and "derived from forward" in r.output, r.output
    js = tmp_path / "r.json"
    r = CliRunner().invoke(cli, ["eval", str(tmp_path / "fwd"), "--gt", str(tmp_path / "gt"),
                                 "--pipeline", "fsr3-interp,mob-fgsr,blend", "--json", str(js),
                                 "--no-progress", "--no-hdr-flip"])
    assert r.exit_code == 0, r.output
    res = json.loads(js.read_text())["pipelines"]
    f = res["fsr3-interp"]["psnr"]
    assert f > res["blend"]["psnr"] + 1.0 and f > res["mob-fgsr"]["psnr"] + 1.0


def test_block_flow_subpixel_and_display_space_options():
    # a half-pixel shift: the SAD-parabola refinement moves the integer vector toward it
    h, w = 64, 96
    big = _texture(h + 16, 2 * (w + 16), 6)
    half = torch.nn.functional.avg_pool2d(big[None], (1, 2))[0]  # (3, h+16, w+16)
    shifted = torch.nn.functional.avg_pool2d(big[:, :, 1:-1][None], (1, 2))[0]
    img0 = half[:, 8:8 + h, 8:8 + w]
    img1 = shifted[:, 8:8 + h, 8:8 + w]  # frame 1 at x shows frame 0 at x + 0.5
    l0, l1 = fsr3.luma8(img0), fsr3.luma8(img1)
    fi = fsr3.block_flow(l0, l1)
    fs = fsr3.block_flow(l0, l1, subpixel=True)
    inner = (slice(None), slice(1, -1), slice(1, -1))
    assert (fs[inner][0] - 0.5).abs().mean() < (fi[inner][0] - 0.5).abs().mean()
    assert fs.abs().max() < 9 and not fsr3.block_flow(l0, l0, subpixel=True).any()
    # display space: exact round trip (HDR included); zero motion stays exact
    x = torch.tensor([0.0, 1e-3, 0.5, 1.0, 7.5])
    assert torch.allclose(fsr3.decode_display(fsr3.encode_display(x)), x, rtol=1e-5, atol=1e-7)
    c = _texture(6, 8)
    z = torch.zeros(2, 6, 8)
    one = torch.ones(1, 6, 8)
    out, _, _ = fsr3.interpolate_fsr3(c, c, z, one, one, 0.5, z, space="display")
    assert torch.allclose(out, c, atol=1e-6)
    with pytest.raises(ValueError):
        fsr3.interpolate_fsr3(c, c, z, one, one, 0.5, space="nope")


def test_flow_is_computed_once_per_pair_with_the_same_result():
    """The optical-flow stage keeps the pair's block flow and frame 1's luminance in the
    run state: two generated frames per pair over three frames give the outputs of
    stateless runs, and each frame's luminance (so each pair's flow) is computed once."""
    from fgcli.ops import fsr3 as FS
    from fgcli.runner import RunState

    f = _frames("blade", 3)
    p = pl.load("fsr3-interp")
    stages = p.build("interp")
    calls = []
    real = FS._luma8_code  # (luma8's codes: from a colour, or from the field's plane)

    def counting(y):
        calls.append(1)
        return real(y)

    st = RunState()
    with torch.inference_mode():
        FS._luma8_code, orig = counting, FS._luma8_code
        try:
            got = [pl.run_stages(stages, dict(make_ctx(f[i], f[i + 1], a, "interp"), state=st,
                                              prev_time=0.0))["color"]
                   for i in (0, 1) for a in (0.25, 0.75)]
        finally:
            FS._luma8_code = orig
        ref = [pl.run_stages(stages, dict(make_ctx(f[i], f[i + 1], a, "interp"), state=None,
                                          prev_time=0.0))["color"]
               for i in (0, 1) for a in (0.25, 0.75)]
    assert all(torch.equal(x, y) for x, y in zip(got, ref))
    assert len(calls) == 3  # frames 0, 1 and 2: each luminance once, each pair's flow once


def test_block_field_option_same_on_both_backends():
    """fsr3-interp:field=block (the SDK's block-grid optical-flow field) runs end to end
    and gives the same frame on the numba and torch backends; it differs from the
    default per-pixel field."""
    pytest.importorskip("numba")
    f = _frames("blade", 2)
    outs = {}
    with torch.inference_mode():
        for name in ("fsr3-interp:field=block", "fsr3-interp"):
            stages = pl.load(name).build("interp")
            for be in ("torch", "numba"):
                ctx = dict(make_ctx(f[0], f[1], 0.5, "interp"), state=None, prev_time=0.0,
                           backend=be)
                outs[name, be] = pl.run_stages(stages, ctx)["color"]
    blk = outs["fsr3-interp:field=block", "torch"]
    assert bool(torch.isfinite(blk).all())
    check("field=block", outs["fsr3-interp:field=block", "numba"], blk, PIPELINE)
    assert not torch.equal(blk, outs["fsr3-interp", "torch"])
