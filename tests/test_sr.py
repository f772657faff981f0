"""Super resolution (--scale): the resampling and upsampling ops, TAAU and Mob-FGSR's SR on
jittered point samples of a known image, the hard cases, and the --scale runs and
evaluation (SS / ESS split, G-buffer-only frames, chunks, frames without jitter)."""
from __future__ import annotations

import json
import math
import os
import shutil

import numpy as np
import pytest
import torch
from click.testing import CliRunner

from fgcli.cli import cli
from fgcli.ops import sr as S

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SAMPLES = os.path.join(ROOT, "sample_data")

# Halton(2, 3) - 0.5: the jitter sequence of `fgen synth --jitter` (and of most engines)


from fgcli.synth.tracer import _halton  # noqa: E402

JITTERS = [(_halton(k, 2) - 0.5, _halton(k, 3) - 0.5) for k in range(1, 17)]


def _pattern(x, y, k=1.0):
    """A 2D signal (3 channels), x, y in HR pixels. k = 1: well below the LR Nyquist limit
    (pi / 2 per HR pixel at scale 2); k = 2.5: detail between the LR and the HR limit,
    which only the jittered history can recover."""
    return torch.stack([0.5 + 0.3 * torch.sin(0.6 * k * x + 0.2 * y),
                        0.5 + 0.3 * torch.cos(0.5 * k * y - 0.2 * x),
                        0.4 + 0.2 * torch.sin(0.4 * k * x) * torch.cos(0.45 * k * y)])


def _lr(h, w, jitter, shift=0.0, k=1.0):
    """Point samples of the pattern at the jittered LR places, in HR pixel units (scale 2):
    LR sample (c, r) lies at ((c + 0.5 + jx) * 2, (r + 0.5 + jy) * 2); `shift` moves the
    pattern by that many HR pixels in x (a pan)."""
    ys, xs = torch.meshgrid(torch.arange(h, dtype=torch.float64),
                            torch.arange(w, dtype=torch.float64), indexing="ij")
    return _pattern((xs + 0.5 + jitter[0]) * 2 - shift, (ys + 0.5 + jitter[1]) * 2, k).float()


def _hr(h, w, shift=0.0, k=1.0):
    ys, xs = torch.meshgrid(torch.arange(2 * h, dtype=torch.float64),
                            torch.arange(2 * w, dtype=torch.float64), indexing="ij")
    return _pattern(xs + 0.5 - shift, ys + 0.5, k).float()


def _rmse(a, b):
    return float(((a - b) ** 2).mean().sqrt())


# ------------------------------------------------------------------------------ ops


def test_lut_is_catmull_rom_at_the_phase_centres():
    lut = S.catmull_rom_lut(32)
    assert lut.shape == (32, 4)
    assert torch.allclose(lut.sum(1), torch.ones(32), atol=1e-6)  # partition of unity
    t = (torch.arange(32, dtype=torch.float32) + 0.5) / 32
    assert torch.allclose(lut, torch.stack(S.cr_weights(t), 1), atol=1e-6)


def test_upscale_reads_the_samples_at_their_jittered_places():
    """Jitter-aware resampling beats the same samples read as if unjittered, for every
    jitter of the sequence (a wrong sign or a missing jitter fails)."""
    h, w = 24, 32
    ref = _hr(h, w)
    for j in JITTERS[:6]:
        lr = _lr(h, w, j)
        good = _rmse(S.upscale(lr, 2, j), ref)
        assert good < _rmse(S.upscale(lr, 2, (0.0, 0.0)), ref)
        assert good < _rmse(S.upscale(lr, 2, (-j[0], -j[1])), ref)
        assert good < 0.02


@pytest.mark.parametrize("size", [(1, 1), (2, 3), (7, 5), (12, 17)])
@pytest.mark.parametrize("scale", [2, 3])
@pytest.mark.parametrize("phases", [None, 32])
def test_phase_filters_equal_the_per_pixel_reference(size, scale, phases):
    """upscale and upsample_geometry work per phase of the HR grid (shifted LR images,
    scalar weights); they must give what the per-pixel evaluation at hr_positions gives:
    resample_cubic for the colour (float32 weights from the same formula: equal within a
    few ulp of the values' range), and for the geometry the 2x2 candidates' nearest
    surface, exactly."""
    h, w = size
    g = torch.Generator().manual_seed(h * 100 + w)
    img = torch.rand(3, h, w, generator=g) * 4.0
    depth = torch.rand(1, h, w, generator=g) + 0.5
    mv = torch.randn(2, h, w, generator=g)
    for j in ((0.0, 0.0), (0.25, -0.25), (-0.4375, 0.2962963), (1.0, -1.0)):
        u, v = S.hr_positions(h, w, scale, j)
        ref = S.resample_cubic(img, u, v, phases)
        got = S.upscale(img, scale, j, phases)
        assert got.shape == ref.shape
        assert torch.allclose(got, ref, rtol=0, atol=4 * 4.0 * 2 ** -23 * 16), j
        d, m, _ = S.upsample_geometry(depth, mv, scale, j)
        x0, y0 = u.floor().long(), v.floor().long()
        best_d = best_i = None
        for dy in (0, 1):
            for dx in (0, 1):
                i = (y0 + dy).clamp(0, h - 1) * w + (x0 + dx).clamp(0, w - 1)
                dd = depth.reshape(-1)[i]
                if best_d is None:
                    best_d, best_i = dd, i
                else:
                    take = dd < best_d
                    best_d, best_i = torch.where(take, dd, best_d), torch.where(take, i, best_i)
        assert torch.equal(d[0], best_d)
        assert torch.equal(m, mv.reshape(2, -1)[:, best_i.reshape(-1)].reshape(m.shape) * scale)


def test_upscale_identity_and_constants():
    img = torch.rand(3, 5, 7)
    assert torch.equal(S.upscale(img, 1), img)
    const = torch.full((3, 6, 9), 0.7)
    for j in ((0.0, 0.0), (0.3, -0.4)):
        up = S.upscale(const, 2, j)
        assert up.shape == (3, 12, 18)
        assert torch.allclose(up, torch.full_like(up, 0.7), atol=1e-6)


def test_upsample_geometry_takes_the_nearest_surface_never_an_average():
    depth = torch.full((1, 6, 8), 10.0)
    depth[:, :, 4:] = 2.0  # a near surface on the right
    mv = torch.zeros(2, 6, 8)
    mv[0, :, 4:] = 1.5
    d, m, extra = S.upsample_geometry(depth, mv, 2, (0.25, 0.0),
                                      {"normal": torch.ones(3, 6, 8)})
    assert d.shape == (1, 12, 16) and m.shape == (2, 12, 16)
    assert set(d.unique().tolist()) <= {2.0, 10.0}  # no depth between the two surfaces
    near = d[0] == 2.0
    assert torch.all(m[0][near] == 3.0) and torch.all(m[0][~near] == 0.0)  # scaled by 2
    assert extra["normal"].shape == (3, 12, 16)
    # the edge leans to the near surface (of the 2x2 samples around a pixel, the nearest)
    assert near.float().mean() > 0.5


DETAIL = 2.5


def _converge(method, frames=12, shift_per_frame=0.0, **kw):
    h, w = 20, 28
    st, errs = {}, []
    for t in range(frames):
        j = JITTERS[t % 16]
        shift = shift_per_frame * t
        lr = _lr(h, w, j, shift, DETAIL)
        depth = torch.full((1, 2 * h, 2 * w), 5.0)
        mv = torch.zeros(2, 2 * h, 2 * w)
        mv[0] = -shift_per_frame  # the pattern pans +x: the previous place is to the left
        if method == "taau":
            out, st["w"] = S.taau(lr, depth, mv, 2, j, st.get("c"), st.get("d"), st.get("w"), **kw)
        else:
            out = S.mobfgsr_sr(lr, depth, mv, 2, j, st.get("c"), st.get("d"), **kw)
        st["c"], st["d"] = out, depth
        ref = _hr(h, w, shift, DETAIL)
        errs.append((_rmse(out, ref), _rmse(S.upscale(lr, 2, j), ref)))
    return errs


@pytest.mark.parametrize("method", ["taau", "mob"])
@pytest.mark.parametrize("pan", [0.0, 0.75])
def test_history_accumulates_detail_beyond_one_frame(method, pan):
    """On a still or panning view, TAAU's and Mob-FGSR's reconstructions from the jittered
    history end up closer to the HR signal (detail above the LR Nyquist limit) than the
    bicubic upscale of the frame alone."""
    errs = _converge(method, shift_per_frame=pan)
    late = errs[6:]
    sr = sum(e[0] for e in late) / len(late)
    up = sum(e[1] for e in late) / len(late)
    # still: ~0.78x the upscale's error; panning (every frame's history resampled): ~0.87x
    assert sr < (0.85 if pan == 0 else 0.93) * up, (sr, up)
    # first frame: the upscale (mob-fgsr's with its 32-phase LUT)
    assert errs[0][0] == pytest.approx(errs[0][1], rel=1e-6 if method == "taau" else 2e-2)


PAPER = dict(samples="eq2", clamp="changed", reactive=None)  # the paper's exact reading


def test_mobfgsr_sr_is_steady_where_the_upscale_flickers():
    """The paper's reading of Mob-FGSR's Eq. 2 blend (a = 0.34) averages the jittered frames: on a still view of
    detail above the LR Nyquist limit, its output changes far less from frame to frame than
    the upscale of each jittered frame (which shows the jitter as flicker). (Its tent over
    the LR samples within one LR pixel does not recover that detail: not asserted.)"""
    h, w = 20, 28
    st, prev, prev_up, d_sr, d_up = {}, None, None, [], []
    for t in range(12):
        j = JITTERS[t % 16]
        lr = _lr(h, w, j, 0.0, DETAIL)
        depth, mv = torch.full((1, 2 * h, 2 * w), 5.0), torch.zeros(2, 2 * h, 2 * w)
        out = S.mobfgsr_sr(lr, depth, mv, 2, j, st.get("c"), st.get("d"), **PAPER)
        st["c"], st["d"] = out, depth
        up = S.upscale(lr, 2, j)
        if t >= 4:
            d_sr.append(float((out - prev).abs().mean()))
            d_up.append(float((up - prev_up).abs().mean()))
        prev, prev_up = out, up
    assert sum(d_sr) < 0.5 * sum(d_up)


@pytest.mark.parametrize("method", ["taau", "mobfgsr"])
def test_wrong_vectors_lose_the_history_gain(method):
    """The history must follow the vectors: with the pan's vectors zeroed the result is
    worse than with them (the test of the reprojection itself)."""
    good = _converge(method, shift_per_frame=1.5)
    h, w = 20, 28
    st, bad = {}, []
    for t in range(12):
        j = JITTERS[t % 16]
        lr = _lr(h, w, j, 1.5 * t, DETAIL)
        depth, mv = torch.full((1, 2 * h, 2 * w), 5.0), torch.zeros(2, 2 * h, 2 * w)
        if method == "taau":
            out, st["w"] = S.taau(lr, depth, mv, 2, j, st.get("c"), st.get("d"), st.get("w"))
        else:
            out = S.mobfgsr_sr(lr, depth, mv, 2, j, st.get("c"), st.get("d"))
        st["c"], st["d"] = out, depth
        bad.append(_rmse(out, _hr(h, w, 1.5 * t, DETAIL)))
    assert sum(e[0] for e in good[6:]) < sum(bad[6:])


@pytest.mark.parametrize("size", [(1, 1), (1, 5), (3, 5), (7, 2)])
def test_hard_cases_stay_finite(size):
    h, w = size
    color = torch.rand(3, h, w) * 100
    color[0, 0, 0] = float("nan")
    color[1, -1, -1] = float("inf")
    depth = torch.full((1, h, w), 3.0)
    depth[0, 0, -1] = float("inf")
    depth[0, -1, 0] = float("nan")
    mv = torch.randn(2, h, w) * 1e7
    mv[1, 0, 0] = float("nan")
    for j in ((0.0, 0.0), (0.49, -0.5), (float("nan"), float("inf"))):
        d, m, _ = S.upsample_geometry(depth, mv, 2, j)
        assert d.shape == (1, 2 * h, 2 * w) and torch.isfinite(m).all()
        assert not torch.isnan(d).any()
        up = S.upscale(color, 2, j)
        assert up.shape == (3, 2 * h, 2 * w) and torch.isfinite(up).all()
        for hist in (None, up):
            t, wgt = S.taau(color, d, m, 2, j, hist, None if hist is None else d,
                            None if hist is None else torch.ones(2 * h, 2 * w))
            assert torch.isfinite(t).all() and torch.isfinite(wgt).all()
            for reactive in (None, 0.25):
                mo = S.mobfgsr_sr(color, d, m, 2, j, hist, None if hist is None else d,
                                  reactive=reactive)
                assert torch.isfinite(mo).all()


# ------------------------------------------------------------------------------ runs


def _run(args, code=0):
    r = CliRunner().invoke(cli, args)
    assert r.exit_code == code, (r.output, r.stderr)
    return r


@pytest.fixture(scope="module")
def lowres(tmp_path_factory):
    """A small random scene rendered at half resolution with jitter (8 frames, 64x36) and
    its full-resolution ground truth on every number; and the same input with every odd
    input frame G-buffer-only."""
    d = tmp_path_factory.mktemp("sr")
    _run(["synth", "--random", "3", str(d / "lowres"), "--gt", str(d / "gt"), "--jitter",
          "--size", "64x36", "--frames", "6", "--no-progress"])
    _run(["synth", "--random", "3", str(d / "gbuf"), "--gt", str(d / "gt2"), "--jitter",
          "--size", "64x36", "--frames", "6", "--gbuffer-only", "odd", "--no-progress"])
    return d


def test_eval_scale_splits_ss_and_ess(lowres, tmp_path):
    js = tmp_path / "r.json"
    r = _run(["eval", str(lowres / "lowres"), "--gt", str(lowres / "gt"), "--scale", "2",
              "--pipeline", "mob-fgsr,taau,upscale,blend", "--no-hdr-flip", "--no-progress",
              "--json", str(js)])
    assert "SS frames" in r.output and "ESS frames" in r.output
    res = json.loads(js.read_text())
    assert res["scale"] == 2 and res["ss_frames"] == [0, 2, 4, 6, 8, 10]
    assert res["ess_frames"] == [1, 3, 5, 7, 9]
    for name, p in res["pipelines"].items():
        for part in ("ss", "ess"):
            for key in ("psnr", "ssim", "flip", "psnr_disoccluded", "psnr_moving",
                        "temporal_change", "ms_per_frame", "frames"):
                assert key in p[part], (name, part, key)
        assert p["ss"]["frames"] == 6 and p["ess"]["frames"] == 5
        assert p["frames"] == 11 and p["psnr"] is not None
    # a pipeline without SR stages reconstructs rendered frames as `upscale` does
    assert res["pipelines"]["blend"]["ss"]["psnr"] == pytest.approx(
        res["pipelines"]["upscale"]["ss"]["psnr"], abs=1e-9)


def test_eval_scale_with_gbuffer_only_frames(lowres, tmp_path):
    """G-buffer-only input frames are never inputs: their numbers are ESS targets."""
    js = tmp_path / "r.json"
    _run(["eval", str(lowres / "gbuf"), "--gt", str(lowres / "gt"), "--scale", "2",
          "--mode", "extrap", "--pipeline", "mob-fgsr,upscale,taau", "--no-hdr-flip",
          "--no-progress", "--json", str(js)])
    res = json.loads(js.read_text())
    assert res["gbuffer_only_inputs"] == [2, 6, 10]
    assert res["inputs"] == [0, 4, 8]
    assert res["ss_frames"] == [0, 4, 8]
    assert {2, 6, 10} <= set(res["ess_frames"])
    for p in res["pipelines"].values():
        assert math.isfinite(p["ess"]["psnr"]) and math.isfinite(p["ss"]["psnr"])


def test_info_and_runs_never_read_colour_from_gbuffer_only_frames(lowres, tmp_path):
    out = tmp_path / "o"
    _run(["extrapolate", str(lowres / "gbuf"), str(out), "--scale", "2", "--pipeline",
          "mob-fgsr", "--alpha", "0.5", "--no-progress"])
    summary = json.loads((out / "fgen-run.json").read_text())
    assert summary["gbuffer_only_inputs"] == [2, 6, 10]
    assert summary["input_frames"] == [0, 4, 8]
    names = sorted(f for f in os.listdir(out) if f.endswith(".exr"))
    assert [int(n.split(".")[-2]) for n in names] == [2, 6, 10]  # the frames filled in
    from fgcli.io.options import open_input

    f = open_input(str(out)).read(6)
    assert f.width == 64 and f.height == 36 and torch.isfinite(f.color).all()  # 2 x 32x18


def test_scale_only_pipelines_need_scale(lowres, tmp_path):
    r = _run(["interpolate", str(lowres / "lowres"), str(tmp_path / "o"), "--pipeline",
              "taau", "--no-progress"], code=2)
    assert "--scale" in r.stderr


def test_taau_chunks_are_byte_identical_to_one_run(lowres, tmp_path):
    from tests.test_farm import assert_same_frames

    base = ["interpolate", str(lowres / "lowres"), None, "--scale", "2", "--pipeline", "taau",
            "--emit", "all", "--no-progress"]
    ref = tmp_path / "ref"
    _run([a if a is not None else str(ref) for a in base])
    out = tmp_path / "out"
    for k in (1, 2, 3):
        _run([a if a is not None else str(out) for a in base] + ["--chunk", f"{k}/3"])
    assert_same_frames(ref, out)


@pytest.mark.parametrize("mode", ["interpolate", "extrapolate"])
def test_emit_all_reconstructs_each_rendered_frame_once(lowres, tmp_path, monkeypatch, mode):
    """With --emit all the copies of the rendered frames go out between the generated
    frames that read them: the recurrent reconstruction runs through the sequence once."""
    from fgcli.io.options import open_input
    from fgcli.sr import Reconstructor

    made = []
    real = Reconstructor._make

    def counting(self, n, timings):
        made.append(n)
        return real(self, n, timings)

    monkeypatch.setattr(Reconstructor, "_make", counting)
    _run([mode, str(lowres / "lowres"), str(tmp_path / "o"), "--scale", "2", "--pipeline",
          "taau", "--emit", "all", "--no-progress"])
    numbers = open_input(str(lowres / "lowres")).numbers
    assert made == list(numbers)


def _without_jitter(src, dst):
    """A copy of a sequence whose headers carry no fgen:jitter_x/y."""
    from fgcli.io import exr

    shutil.copytree(src, dst)
    for f in os.listdir(dst):
        if f.endswith(".exr"):
            p = str(dst / f)
            h = exr.read_header(p)
            names = [c for _, c, _ in h.all_channels()]
            chans = exr.read_channels(p, [(0, c) for c in names], h)
            attrs = {k: v for k, v in h.attributes.items() if not k.startswith("fgen:jitter")}
            exr.write_exr(p, {n: chans[(0, n)] for n in names},
                          {n: "float" for n in names}, attrs, "zip")
    return dst


def test_input_without_jitter_is_a_warning_not_an_error(lowres, tmp_path):
    """Frames without jitter metadata are scored as jitter 0, with a warning."""
    plain = _without_jitter(lowres / "lowres", tmp_path / "plain")
    r = _run(["eval", str(plain), "--gt", str(lowres / "gt"), "--scale", "2", "--pipeline",
              "upscale", "--no-hdr-flip", "--no-progress"])
    assert "jitter" in r.stderr and "scored as jitter 0" in r.stderr


def test_scaled_outputs_carry_consistent_geometry(lowres, tmp_path):
    """--scale 2 outputs: every plane at twice the size, depth only values the input had,
    vectors of the rendered frames scaled by 2 where the input's were kept."""
    from fgcli.io.options import open_input

    out = tmp_path / "o"
    _run(["interpolate", str(lowres / "lowres"), str(out), "--scale", "2", "--pipeline",
          "upscale", "--emit", "all", "--no-progress"])
    src = open_input(str(lowres / "lowres"))
    got = open_input(str(out))
    assert (got.width, got.height) == (2 * src.width, 2 * src.height)
    f_in, f_out = src.read(0), got.read(0)
    ins = set(np.unique(f_in.depth.numpy()).tolist())
    assert set(np.unique(f_out.depth.numpy()).tolist()) <= ins


def test_jitter_from_a_sidecar_and_from_the_projection(lowres, tmp_path):
    """jitter_px in cameras.json, and an off-centre principal point: a jittered projection
    moves a point's image by -jitter (the pixel at c + 0.5 shows what the unjittered grid
    has at c + 0.5 + jx), which frame_jitter reads back."""
    from fgcli.frame import Camera
    from fgcli.io.cameras import project
    from fgcli.io.options import open_input
    from fgcli.sr import frame_jitter

    d = _without_jitter(lowres / "lowres", tmp_path / "side")
    side = json.loads((d / "cameras.json").read_text())
    for e in side["frames"]:
        e["jitter_px"] = [0.125, -0.375]
    (d / "cameras.json").write_text(json.dumps(side))
    r = open_input(str(d))
    f = r.read(r.numbers[1])
    assert frame_jitter(f) == (0.125, -0.375)
    f.header.pop("fgen:jitter_x"), f.header.pop("fgen:jitter_y")
    cam = f.camera
    W, H = f.width, f.height
    jx, jy = 0.3, -0.2
    p = np.array(cam.projection, dtype=np.float64)
    p[0, 2], p[1, 2] = 2 * jx / W, -2 * jy / H
    jittered = Camera(cam.world_to_camera, p)
    pt = np.linalg.inv(np.asarray(cam.world_to_camera, np.float64)) @ np.array([0.3, -0.2, -5.0, 1.0])
    a = project(cam, pt[None, :3], W, H)[0, :2]
    b = project(jittered, pt[None, :3], W, H)[0, :2]
    assert b[0] - a[0] == pytest.approx(-jx, abs=1e-6)
    assert b[1] - a[1] == pytest.approx(-jy, abs=1e-6)
    got = frame_jitter(f.replace(camera=jittered))
    assert got == pytest.approx((jx, jy), abs=1e-9)
    assert frame_jitter(f) is None  # the synth's projection is the unjittered one


def test_a_gbuffer_only_first_frame(lowres, tmp_path):
    """A sequence that starts with a frame that was not shaded: the layout comes from the
    shaded frames, the run and the evaluation start at the first shaded frame."""
    d = tmp_path / "g"
    shutil.copytree(lowres / "gbuf", d)
    os.unlink(d / [f for f in os.listdir(d) if f.endswith(".0000.exr")][0])
    r = _run(["info", str(d), "--json"])
    info = json.loads(r.stdout if hasattr(r, "stdout") else r.output)
    assert info["gbuffer_only"][:1] == [2] and info["frames"][0] == 4
    out = tmp_path / "o"
    _run(["extrapolate", str(d), str(out), "--scale", "2", "--pipeline", "mob-fgsr",
          "--no-progress"])
    js = tmp_path / "r.json"
    _run(["eval", str(d), "--gt", str(lowres / "gt"), "--scale", "2", "--mode", "extrap",
          "--pipeline", "taau,upscale", "--no-hdr-flip", "--no-progress", "--json", str(js)])
    res = json.loads(js.read_text())
    assert res["inputs"][0] == 4 and 2 in res["gbuffer_only_inputs"]
    for p in res["pipelines"].values():
        assert math.isfinite(p["ss"]["psnr"]) and math.isfinite(p["ess"]["psnr"])


def test_info_lists_gbuffer_only_frames():
    r = _run(["info", os.path.join(SAMPLES, "orbit", "lowres_gbuffer")])
    assert "G-buffer-only: 8 frames" in r.output and "jitter" in r.output


def test_a_camera_cut_drops_the_history(lowres, tmp_path):
    """Two shots in one sequence: the SR history never crosses the cut (the reconstruction
    of the first frame after it is the frame's own upscale) and every output is finite."""
    from fgcli.io.options import open_input

    other = tmp_path / "other"
    _run(["synth", "--random", "11", str(other / "lowres"), "--gt", str(other / "gt"),
          "--jitter", "--size", "64x36", "--frames", "6", "--no-progress"])
    cut = tmp_path / "cut"
    cut.mkdir()
    for src, numbers, offset in ((lowres / "lowres", (0, 2, 4, 6), 0),
                                 (other / "lowres", (0, 2, 4, 6), 8)):
        for n in numbers:
            name = [f for f in os.listdir(src) if f.endswith(f".{n:04d}.exr")][0]
            shutil.copy(src / name, cut / f"shot.{n + offset:04d}.exr")
    out = tmp_path / "o"
    _run(["interpolate", str(cut), str(out), "--scale", "2", "--pipeline", "taau", "--emit",
          "all", "--no-progress"])
    summary = json.loads((out / "fgen-run.json").read_text())
    assert summary["sr_history_reset_at_cuts"] == [8]
    got = open_input(str(out))
    first_after = got.read(8 * got.step // 2 if got.step > 1 else 8)
    src = open_input(str(cut)).read(8)
    from fgcli.sr import frame_jitter

    assert torch.allclose(first_after.color, S.upscale(src.color, 2, frame_jitter(src)),
                          atol=2e-3 * max(1.0, float(src.color.max())))  # half-float output
    for n in got.numbers:
        assert torch.isfinite(got.read(n).color).all()


@pytest.mark.parametrize("name", ["upscale", "taau", "mob-fgsr", "blend"])
@pytest.mark.parametrize("size", [(1, 1), (3, 5), (8, 13)])
def test_sr_stages_on_hard_frames(name, size):
    """Every pipeline's --scale 2 path (its SR stages, or the upscale, then generation at
    the output size) over the hard cases: 1x1 and odd sizes, NaN / huge colour, inf / NaN
    depth, NaN / huge vectors, no jitter, an empty history, a cut between frames."""
    from fgcli import pipeline as pl
    from fgcli.frame import Frame
    from fgcli.runner import RunState
    from fgcli.sr import Reconstructor, generate

    h, w = size
    g = torch.Generator().manual_seed(h * 31 + w)
    frames = []
    for n in range(4):
        color = torch.rand(3, h, w, generator=g) * (65504.0 if n == 2 else 1.0)
        color[0, 0, 0] = float("nan")
        depth = torch.rand(1, h, w, generator=g) + 0.5
        depth[0, -1, -1] = float("inf")
        if h * w > 1:
            depth[0, 0, -1] = float("nan")
        mv = torch.randn(2, h, w, generator=g) * (1e6 if n == 3 else 2.0)
        mv[1, -1, 0] = float("nan")
        header = {} if n == 1 else {"fgen:jitter_x": JITTERS[n][0],
                                     "fgen:jitter_y": JITTERS[n][1]}
        frames.append(Frame(number=2 * n, color=color, depth=depth, mv=mv, header=header))
    p = pl.load(name)
    for mode in p.modes:
        rec = Reconstructor(p, 2, lambda k: frames[k // 2], [0, 2, 4, 6], "torch")
        stages, state = p.build(mode), RunState()
        for i in range(1, 4):
            hr = rec.frame(2 * i)
            assert hr.color.shape == (3, 2 * h, 2 * w) and torch.isfinite(hr.color).all()
            assert hr.mv.shape == (2, 2 * h, 2 * w) and torch.isfinite(hr.mv).all()
            ctx = generate(stages, p.has_sr, rec, frames[i - 1], frames[i], 0.5, mode, state,
                           2, "torch")
            assert ctx["color"].shape == (3, 2 * h, 2 * w)
            assert torch.isfinite(ctx["color"]).all() and torch.isfinite(ctx["mv"]).all()
        assert rec.no_jitter == [2]
