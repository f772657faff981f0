"""mv-interp: guiding flows, cue channels, network, shipped weights (onnxruntime vs torch),
training loop (seeded, resumable), the pipeline end to end on odd sizes and 1x1."""
from __future__ import annotations

import os

import numpy as np
import pytest
import torch

from fgcli.ops._testing import moving_square
from fgcli.ops.mvinterp import guide_cues, guide_warp, guiding_flows, tonemap, untonemap


def test_guiding_flows_follow_the_square():
    # square moves right 4 px per frame; at t = 0.5 its left column is 18
    c0, d0, mv0 = moving_square(0.0)
    c1, d1, mv1 = moving_square(1.0)
    ch, dh, _ = moving_square(0.5)
    to0, to1, holes = guiding_flows(d1, mv1, 0.5, mv0, d0)
    # on the square at t = 0.5 (away from the dilated edge): half a frame each way
    assert torch.equal(to0[0, 9:13, 19:23], torch.full((4, 4), -2.0))
    assert torch.equal(to1[0, 9:13, 19:23], torch.full((4, 4), 2.0))
    assert to0.shape == (2, 24, 40) and holes.shape == (1, 24, 40) and holes.dtype == torch.bool
    out = guide_warp(c0, c1, to0, to1, 0.5)
    # the generated square's interior matches the true frame
    assert torch.allclose(out[:, 9:13, 19:23], ch[:, 9:13, 19:23], atol=1e-5)
    # without frame 0's vectors: the paper's linear rule, still finite
    a0, a1, h2 = guiding_flows(d1, mv1, 0.5)
    assert torch.isfinite(a0).all() and torch.isfinite(a1).all()


def test_guide_cues_sky_and_range():
    d0 = torch.full((1, 8, 8), float("inf"))
    d1 = d0.clone()
    d1[:, 2:4, 2:4] = 3.0
    z = torch.zeros(2, 8, 8)
    cue = guide_cues(d0, d1, z, z, torch.zeros(1, 8, 8, dtype=torch.bool))
    assert torch.isfinite(cue).all()
    assert cue[0, 0, 0] == 0  # sky against sky: same depth
    assert cue[0, 2, 2] == 1.0  # frame 1 sample nearer than sky: clamped ratio, +1
    assert cue[1].sum() == 0


def test_tonemap_roundtrip_and_hdr():
    x = torch.tensor([0.0, 1e-4, 0.5, 1.0, 7.0, 100.0])
    assert torch.allclose(untonemap(tonemap(x)), x, rtol=1e-5, atol=1e-6)
    assert tonemap(torch.tensor([1e4])) == tonemap(torch.tensor([100.0]))


def test_net_warp_matches_ops_backward_warp():
    from fgcli.nets.blocks import warp
    from fgcli.ops import backward_warp

    g = torch.Generator().manual_seed(1)
    img = torch.rand(1, 3, 20, 30, generator=g)
    flow = (torch.rand(1, 2, 20, 30, generator=g) - 0.5) * 6
    a = warp(img, flow)
    b, _ = backward_warp(img[0], flow[0])
    # both bilinear with clamped borders; grid_sample's normalised coordinates round
    # differently (~1e-6 px), so compare within float32 interpolation noise
    assert torch.allclose(a[0], b, atol=1e-4)


def test_untrained_network_is_the_even_guided_blend():
    from fgcli.nets.blocks import warp
    from fgcli.nets.mvinterp import MVInterpNet

    torch.manual_seed(0)
    net = MVInterpNet().eval()
    g = torch.Generator().manual_seed(2)
    c0, c1 = torch.rand(1, 3, 32, 48, generator=g), torch.rand(1, 3, 32, 48, generator=g) * 4
    g0, g1 = torch.randn(1, 2, 32, 48, generator=g), torch.randn(1, 2, 32, 48, generator=g)
    cue = torch.zeros(1, 2, 32, 48)
    with torch.no_grad():
        out, f0, f1, m = net(c0, c1, g0, g1, cue, torch.full((1, 1, 1, 1), 0.3))
    # zero-initialised heads: flows = guides, mask = 0.5, residual = 0 (exact HDR blend)
    assert torch.equal(f0, g0) and torch.equal(f1, g1)
    assert torch.all(m == 0.5)
    assert torch.allclose(out, 0.5 * warp(c0, g0) + 0.5 * warp(c1, g1), atol=1e-6)


def test_losses():
    from fgcli.nets.blocks import census, charbonnier

    x = torch.rand(2, 3, 16, 16)
    assert census(x, x) == 0
    assert abs(float(charbonnier(x, x)) - 1e-3) < 1e-6  # sqrt(eps)
    y = x.clone()
    y[..., 8, 8] += 0.5
    assert census(x, y) > 0 and charbonnier(x, y) > charbonnier(x, x)


# ---------------------------------------------------------------- shipped weights

def test_shipped_weights_load_from_the_package_and_backends_agree():
    from fgcli.nets.export import WEIGHTS_DIR
    from fgcli.nets.runtime import run_mvinterp

    assert os.path.exists(os.path.join(WEIGHTS_DIR, "mv-interp.onnx"))
    assert os.path.getsize(os.path.join(WEIGHTS_DIR, "mv-interp.onnx")) < 8e6
    g = torch.Generator().manual_seed(3)
    c0 = torch.rand(1, 3, 48, 80, generator=g) * 2
    c1 = torch.rand(1, 3, 48, 80, generator=g) * 2
    g0 = torch.randn(1, 2, 48, 80, generator=g) * 3
    g1 = -g0
    cue = torch.zeros(1, 2, 48, 80)
    cue[:, 1, 10:20, 10:20] = 1
    a = run_mvinterp(c0, c1, g0, g1, cue, 0.4, backend="onnx")
    b = run_mvinterp(c0, c1, g0, g1, cue, 0.4, backend="torch")
    # same graph, other kernels (onnxruntime fuses conv + activation, sums in another
    # order): float32 differences of ~1e-6 relative per layer, ~1e-4 after the network
    for x, y in zip(a, b):
        assert x.shape == y.shape
        assert torch.allclose(x, y, atol=2e-3, rtol=1e-3), float((x - y).abs().max())


# ---------------------------------------------------------------- training

@pytest.fixture(scope="module")
def tiny_data(tmp_path_factory):
    from fgcli.nets.data import make_samples

    d = tmp_path_factory.mktemp("mvdata")
    make_samples(str(d / "train"), [0, 1], size=(64, 48), progress=False)
    make_samples(str(d / "val"), [1_000_000], size=(64, 48), progress=False)
    return d


def test_training_data_is_deterministic(tiny_data):
    from fgcli.nets.data import render_interp_sample, sample_path

    a = render_interp_sample(1, size=(64, 48))
    with np.load(sample_path(str(tiny_data / "train"), 1)) as z:
        for k in ("c0", "c1", "gt", "g0", "g1", "cue"):
            assert np.array_equal(a[k], z[k]), k


def _task(d):
    from fgcli.nets.mvinterp_train import MVInterpTask

    return MVInterpTask(str(d / "train"), str(d / "val"), patch=32, batch=2)


def test_training_resumes_exactly(tiny_data, tmp_path):
    """An uninterrupted run and one stopped (Ctrl-C) after 3 of 5 steps and continued end
    with byte-identical weights (same machine) and one loss row per step."""
    from fgcli.nets.train import train

    def run(folder, stop_at=None):
        task = _task(tiny_data)
        if stop_at is not None:
            batch = task.batch

            def interrupting(seed, step):
                if step == stop_at:
                    raise KeyboardInterrupt
                return batch(seed, step)

            task.batch = interrupting
        torch.manual_seed(0)
        return train(task, str(folder), 5, lr=1e-3, ckpt_every=2, val_every=4,
                     progress=False, log=lambda m: None)

    ref = run(tmp_path / "a")
    assert ref["steps"] == 5
    with pytest.raises(KeyboardInterrupt):
        run(tmp_path / "b", stop_at=3)
    assert torch.load(tmp_path / "b" / "last.pt", weights_only=False)["step"] == 3
    run(tmp_path / "b")
    a = torch.load(tmp_path / "a" / "last.pt", weights_only=False)
    b = torch.load(tmp_path / "b" / "last.pt", weights_only=False)
    assert a["step"] == b["step"] == 5
    for k in a["model"]:
        assert torch.equal(a["model"][k], b["model"][k]), k
    rows_a = (tmp_path / "a" / "loss.csv").read_text().splitlines()
    rows_b = (tmp_path / "b" / "loss.csv").read_text().splitlines()
    assert len(rows_a) == len(rows_b) == 6  # header + 5 steps
    assert [r.split(",")[1] for r in rows_a] == [r.split(",")[1] for r in rows_b]
    assert (tmp_path / "b" / "best.pt").exists()


# ---------------------------------------------------------------- pipeline

def _frames(h, w, seed=0, sky=False):
    from fgcli.frame import Frame

    g = torch.Generator().manual_seed(seed)
    out = []
    for i in range(2):
        c = torch.rand(3, h, w, generator=g) * 2
        d = 1 + torch.rand(1, h, w, generator=g) * 5
        if sky:
            d[:, : max(1, h // 3)] = float("inf")
        mv = (torch.rand(2, h, w, generator=g) - 0.5) * 6
        out.append(Frame(number=i, color=c, depth=d, mv=mv))
    return out


@pytest.mark.parametrize("h,w", [(1, 1), (1, 7), (9, 1), (17, 29), (37, 53)])
def test_pipeline_any_size_finite(h, w):
    from fgcli import pipeline as pl
    from fgcli.runner import make_ctx

    f0, f1 = _frames(h, w, sky=h > 3)
    for variant in ("mv-interp", "mv-interp:network=off"):
        p = pl.load(variant)
        ctx = pl.run_stages(p.build("interp"), make_ctx(f0, f1, 0.5, "interp"), pl.Timings(),
                            label="1")
        assert ctx["color"].shape == (3, h, w) and ctx["mv"].shape == (2, h, w)
        assert ctx["depth"].shape == (1, h, w)
        assert torch.isfinite(ctx["color"]).all() and torch.isfinite(ctx["mv"]).all()
        assert (ctx["color"] >= 0).all()


def test_pipeline_hard_inputs_stay_finite():
    from fgcli import pipeline as pl
    from fgcli.runner import make_ctx

    f0, f1 = _frames(24, 40, sky=True)
    f1.color[0, 3, 3] = float("nan")
    f1.color[1, 4, 4] = float("inf")
    f1.mv[:, 5, 5] = float("nan")
    f1.mv[:, 6, 6] = 1e9  # a vector far off-screen
    f0.color[:, 7, 7] = 5e4  # HDR far above the tone-map clip
    ctx = pl.run_stages(pl.load("mv-interp").build("interp"), make_ctx(f0, f1, 0.3, "interp"),
                        pl.Timings(), label="1")
    for k in ("color", "depth", "mv"):
        assert not torch.isnan(ctx[k]).any(), k
    assert torch.isfinite(ctx["color"]).all()


def test_zero_motion_skips_the_guide():
    from fgcli import pipeline as pl
    from fgcli.runner import make_ctx

    f0, f1 = _frames(16, 16)
    f0.mv.zero_()
    f1.mv.zero_()
    tm = pl.Timings()
    ctx = pl.run_stages(pl.load("mv-interp").build("interp"), make_ctx(f0, f1, 0.5, "interp"),
                        tm, label="1")
    assert "guide" in {s for _, s, _ in tm.skipped}
    assert torch.isfinite(ctx["color"]).all()


def test_cli_interpolate_with_the_shipped_network(tmp_path):
    from click.testing import CliRunner

    from fgcli.cli import cli
    from fgcli.io.frames import read_frame

    r = CliRunner().invoke(cli, ["synth", "--random", "3", str(tmp_path / "in"), "--size",
                                 "40x24", "--frames", "3", "--no-progress"])
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(cli, ["interpolate", str(tmp_path / "in"), str(tmp_path / "out"),
                                 "--pipeline", "mv-interp", "--no-progress"])
    assert r.exit_code == 0, r.output
    outs = sorted(os.listdir(tmp_path / "out"))
    exrs = [o for o in outs if o.endswith(".exr")]
    assert len(exrs) == 2
    f = read_frame(str(tmp_path / "out" / exrs[0]), 1)
    assert f.header.get("fgen:pipeline") == "mv-interp"
    assert torch.isfinite(f.color).all() and f.mv is not None


def test_export_roundtrip(tiny_data, tmp_path):
    """A (briefly) trained checkpoint exports to ONNX + state dict, and both backends of the
    exported weights agree at a size other than the export's."""
    from fgcli.nets.export import export_mvinterp
    from fgcli.nets.runtime import run_mvinterp
    from fgcli.nets.train import train

    train(_task(tiny_data), str(tmp_path / "run"), 3, lr=1e-2, ckpt_every=3, val_every=3,
          progress=False, log=lambda m: None)
    info = export_mvinterp(str(tmp_path / "run" / "best.pt"), str(tmp_path / "w"), name="t")
    assert info["step"] == 3 and info["widths"] == [16, 24, 32, 48]
    g = torch.Generator().manual_seed(5)
    c0, c1 = torch.rand(1, 3, 32, 48, generator=g), torch.rand(1, 3, 32, 48, generator=g)
    g0 = torch.randn(1, 2, 32, 48, generator=g)
    cue = torch.zeros(1, 2, 32, 48)
    a = run_mvinterp(c0, c1, g0, -g0, cue, 0.5, backend="onnx", folder=str(tmp_path / "w"),
                     name="t")
    b = run_mvinterp(c0, c1, g0, -g0, cue, 0.5, backend="torch", folder=str(tmp_path / "w"),
                     name="t")
    for x, y in zip(a, b):
        assert torch.allclose(x, y, atol=2e-3, rtol=1e-3)
    # trained for 3 steps at a high rate: no longer the untrained even blend
    assert not torch.all(b[3] == 0.5)


def test_noguide_ablation_weights_run():
    from fgcli import pipeline as pl
    from fgcli.runner import make_ctx

    f0, f1 = _frames(17, 29, sky=True)
    p = pl.load("mv-interp:guide=off,weights=mv-interp-noguide")
    tm = pl.Timings()
    ctx = pl.run_stages(p.build("interp"), make_ctx(f0, f1, 0.5, "interp"), tm, label="1")
    assert "guide" not in tm.summary()["stages"]
    assert ctx["color"].shape == (3, 17, 29) and torch.isfinite(ctx["color"]).all()


def test_shading_only_scenes_move_only_the_light():
    from fgcli.nets.data import shading_only
    from fgcli.synth import load_scene, random_scene, render

    for seed in (0, 5):
        spec = shading_only(random_scene(seed, size=(48, 32), frames=3), np.random.default_rng(1))
        assert spec["camera"]["type"] == "static"
        assert all(o["motion"] == {"type": "static"} and "spin" not in o for o in spec["objects"])
        assert all("motion" in lt for lt in spec["lights"])
        scene = load_scene(spec)
        f = render(scene, 1.0, 0.0, spp=1)
        assert float(f.mv.abs().max()) < 1e-3  # static geometry: (numerically) zero vectors


def test_hole_weight_reweights_the_charbonnier_term(tiny_data):
    """--hole-weight: without guide holes in the batch the loss is the plain one; with
    holes it weighs their error up, normalised so a uniform error keeps its value."""
    from fgcli.nets.mvinterp_train import MVInterpTask

    plain = _task(tiny_data)
    weighted = MVInterpTask(str(tiny_data / "train"), str(tiny_data / "val"), patch=32,
                            batch=2, hole_weight=4.0)
    assert weighted.config()["hole_weight"] == 4.0 and "hole_weight" not in plain.config()
    b = plain.batch(0, 0)
    model = plain.model
    with torch.no_grad():
        b["cue"][:, 1] = 0.0
        assert torch.allclose(plain.loss(model, b)["charbonnier"],
                              weighted.loss(model, b)["charbonnier"], rtol=1e-5)
        b["cue"][:, 1, :4] = 1.0  # holes where the error is large
        b["gt"][:, :, :4] += 0.5
        assert weighted.loss(model, b)["charbonnier"] > plain.loss(model, b)["charbonnier"]


def test_occlusion_weight_reweights_different_surface_pixels(tiny_data):
    """--occlusion-weight: pixels whose guided samples are different surfaces (|depth cue|
    >= OCCLUSION_CUE) weigh more; with none in the batch the loss is the plain one."""
    from fgcli.nets.mvinterp_train import OCCLUSION_CUE, MVInterpTask

    plain = _task(tiny_data)
    weighted = MVInterpTask(str(tiny_data / "train"), str(tiny_data / "val"), patch=32,
                            batch=2, occlusion_weight=4.0)
    assert weighted.config()["occlusion_weight"] == 4.0
    assert "occlusion_weight" not in plain.config()
    b = plain.batch(0, 0)
    model = plain.model
    with torch.no_grad():
        b["cue"][:, 0] = 0.5 * OCCLUSION_CUE  # same surface everywhere
        assert torch.allclose(plain.loss(model, b)["charbonnier"],
                              weighted.loss(model, b)["charbonnier"], rtol=1e-5)
        b["cue"][:, 0, :4] = -OCCLUSION_CUE  # different surfaces where the error is large
        b["gt"][:, :, :4] += 0.5
        assert weighted.loss(model, b)["charbonnier"] > plain.loss(model, b)["charbonnier"]


@pytest.mark.parametrize("with_mv0", [False, True])
def test_holes_the_dilation_made_take_frame_1s_own_vectors(with_mv0):
    """A static background pixel beside a moving nearer object is dilated to the object's
    vector and splats away with it, leaving its own place at t empty. undilated=True gives
    that hole frame 1's own (zero) vector and clears it; the real disocclusion next to it
    stays a hole with the fallback vector. Same on the numba path."""
    from fgcli.kernels import ops as K
    from fgcli.ops.mvinterp import guiding_flows

    H, W = 6, 20
    d1 = torch.full((1, H, W), 10.0)
    m1 = torch.zeros(2, H, W)
    d1[:, :, 8:11] = 5.0
    m1[0, :, 8:11] = 4.0  # frame-1 pixel q was at q + 4 in frame 0
    mv0 = d0 = None
    if with_mv0:
        # frame 0: the object at columns 12-14, and another near surface over column 7
        d0 = torch.full((1, H, W), 10.0)
        mv0 = torch.zeros(2, H, W)
        d0[:, :, 12:15] = 5.0
        mv0[0, :, 12:15] = 4.0
        d0[:, :, 6:8] = 4.0
        mv0[0, :, 6:8] = -6.0
    old = guiding_flows(d1, m1, 0.5, mv0, d0, undilated=False)
    new = guiding_flows(d1, m1, 0.5, mv0, d0)
    assert bool(old[2][0, :, 7].all()) and bool(old[2][0, :, 8].all())
    assert not bool(new[2][0, :, 7].any()) and bool(new[2][0, :, 8].all())
    assert torch.equal(new[0][:, :, 7], torch.zeros(2, H))
    assert torch.equal(new[1][:, :, 7], torch.zeros(2, H))
    if with_mv0:
        assert float(old[0][0, 2, 7]) == -3.0  # frame 0's occluder vector: wrong here
    others = [c for c in range(W) if c != 7]
    for a, b in zip(old, new):  # nothing else changes
        assert torch.equal(a[..., others], b[..., others])
    for a, b in zip(new, K.guiding_flows(d1, m1, 0.5, mv0, d0)):
        assert torch.equal(a, b)
