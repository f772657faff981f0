"""fgen synth: scene loading, exact buffers, effects that cost nothing when off, the
frame-number timeline, determinism, the CLI and the shipped sample data."""
from __future__ import annotations

import json
import os
import re

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from click.testing import CliRunner

from fgcli.cli import cli
from fgcli.errors import InputError
from fgcli.io.cameras import project
from fgcli.io.exr import read_channels, read_header
from fgcli.ops.metrics import psnr
from fgcli.synth import load_scene, random_scene, render, render_sequence, schedule
from fgcli.synth import tracer

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SAMPLES = os.path.join(ROOT, "sample_data")
SCENES = os.path.join(SAMPLES, "scenes")
NAMES = ("orbit", "blade", "shadows", "throw")
SMALL = (96, 64)


def scene(name, size=SMALL, **kw):
    return load_scene(os.path.join(SCENES, f"{name}.toml"), size=size, **kw)


def scene_dict(name):
    import tomllib

    with open(os.path.join(SCENES, f"{name}.toml"), "rb") as fh:
        return tomllib.load(fh)


# ----------------------------------------------------------------------------- helpers

def pixel_grid(H, W):
    return torch.meshgrid(torch.arange(H) + 0.5, torch.arange(W) + 0.5, indexing="ij")


def backward_warp(img, mv):
    """Bilinear sample of img (C, H, W) at xy + mv (pixels)."""
    C, H, W = img.shape
    ys, xs = pixel_grid(H, W)
    g = torch.stack([(xs + mv[0]) * (2.0 / W) - 1, (ys + mv[1]) * (2.0 / H) - 1], -1)
    return F.grid_sample(img[None], g[None], mode="bilinear", padding_mode="border",
                         align_corners=False)[0]


def warp_valid(cur_mv, cur_x, prev_x):
    """Pixels a backward warp can reproduce: the surface point was visible and on screen at
    the previous time, no light started or stopped reaching it (moving shadow), the pixel
    sees one object only, and the four bilinear taps all land on that object, away from its
    silhouette, in the previous frame."""
    lit = F.max_pool2d(cur_x["light_changed"][None, None].float(), 3, 1, 1)[0, 0] > 0
    ok = ~cur_x["disoccluded"] & ~cur_x["edge"] & ~lit
    H, W = ok.shape
    ys, xs = pixel_grid(H, W)
    px, py = xs + cur_mv[0] - 0.5, ys + cur_mv[1] - 0.5
    x0, y0 = torch.floor(px).long(), torch.floor(py).long()
    for dy in (0, 1):
        for dx in (0, 1):
            xx, yy = (x0 + dx).clamp(0, W - 1), (y0 + dy).clamp(0, H - 1)
            ok &= (prev_x["object_id"][yy, xx] == cur_x["object_id"]) & ~prev_x["edge"][yy, xx]
    return ok


def warp_psnr(sc, t, prev_t, role="gt"):
    pe, ce = {}, {}
    prev = render(sc, prev_t, prev_t - (t - prev_t), extras=pe, role=role)
    cur = render(sc, t, prev_t, extras=ce, role=role)
    valid = warp_valid(cur.mv, ce, pe)
    # PSNR as `fgen eval` scores it: sRGB of clip(color, 0, 1)
    return psnr(backward_warp(prev.color, cur.mv), cur.color, valid), valid.float().mean().item()


# ----------------------------------------------------------------------------- scenes

def test_sample_scenes_load():
    for n in NAMES:
        sc = load_scene(os.path.join(SCENES, f"{n}.toml"))
        assert (sc.width, sc.height, sc.frames) == (256, 144, 17)
        assert sc.name == n
    assert set(scene("blade").effects) >= {"shadows", "translucency"}
    assert scene("throw").has("reflection")


def test_overrides():
    sc = scene("orbit", size=(40, 30), fps=60, frames=5, spp=2)
    assert (sc.width, sc.height, sc.fps, sc.frames, sc.spp) == (40, 30, 60.0, 5, 2)
    assert sc.hash != scene("orbit", size=(40, 31)).hash
    f = render(sc, 1, 0)
    assert f.color.shape == (3, 30, 40)


@pytest.mark.parametrize("patch, key", [
    ({"effects": ["shadows", "bloom"]}, "effects"),
    ({"camera": {"type": "orbit", "radius": "far"}}, "camera.radius"),
    ({"objects": [{"type": "cube"}]}, "objects[0].type"),
    ({"objects": [{"type": "sphere", "colour": [1, 0, 0]}]}, "objects[0].colour"),
    ({"objects": [{"type": "box", "size": [1, 2]}]}, "objects[0].size"),
    ({"objects": [{"type": "box", "motion": {"type": "linear"}}]}, "objects[0].motion.velocity"),
    ({"lights": [{"type": "point"}]}, "lights[0].position"),
    ({"camera": {"type": "static", "position": [0, 1, 0], "target": [0, 1, 0]}}, "camera.target"),
    ({"frames": 0}, "frames"),
    ({"camera": {"type": "orbit", "follow": {"object": "nobody"}}}, "camera.follow.object"),
])
def test_bad_scene_names_key(patch, key):
    d = scene_dict("orbit")
    d.update(patch)
    with pytest.raises(InputError, match=re.escape(f"'{key}'")):
        load_scene(d)


def test_bad_files(tmp_path):
    p = tmp_path / "bad.toml"  # the message names the file and the key
    p.write_text('size = [8, 8]\neffects = ["nope"]\n[camera]\ntype = "orbit"\n'
                 '[[objects]]\ntype = "sphere"\n')
    with pytest.raises(InputError, match=r"bad\.toml.*'effects'.*unknown effect 'nope'"):
        load_scene(p)
    with pytest.raises(InputError, match="not found"):
        load_scene(tmp_path / "missing.toml")
    p = tmp_path / "broken.toml"
    p.write_text("size = [1, \n")
    with pytest.raises(InputError, match="TOML"):
        load_scene(p)


# ----------------------------------------------------------------------------- exact buffers

@pytest.mark.parametrize("name", NAMES)
def test_backward_warp_reproduces_frame(name):
    """Frame t-1 warped by frame t's vectors is frame t, wherever a warp can be right."""
    sc = scene(name)
    for t, prev in ((4.0, 3.0), (11.0, 10.0), (8.5, 8.0)):  # input rate, and a fine-rate pair
        psnr, frac = warp_psnr(sc, t, prev)
        assert psnr > 35.0, (name, t, psnr)
        assert frac > 0.75, (name, t, frac)


def test_vectors_match_the_cameras():
    """Static geometry and sky: unproject each pixel with depth and the frame's camera,
    project with the previous frame's camera (fgcli.io.cameras): that is xy + mv."""
    sc = scene("orbit")
    prev, cur = render(sc, 2.0, 1.0), render(sc, 3.0, 2.0)
    H, W = cur.height, cur.width
    ys, xs = pixel_grid(H, W)
    P = np.asarray(cur.camera.projection)
    ndc_x, ndc_y = (xs.numpy() / W) * 2 - 1, 1 - (ys.numpy() / H) * 2
    view = np.stack([ndc_x / P[0, 0], ndc_y / P[1, 1], -np.ones_like(ndc_x)], -1)
    depth = cur.depth[0].numpy().astype(np.float64)
    sky = ~np.isfinite(depth)
    assert sky.any() and (~sky).any()
    inv = np.linalg.inv(np.asarray(cur.camera.world_to_camera))
    pts = view[~sky] * depth[~sky][:, None]
    world = (inv[:3, :3] @ pts.T).T + inv[:3, 3]
    q = project(prev.camera, world, W, H)
    want = np.stack([xs.numpy()[~sky], ys.numpy()[~sky]], 1) + cur.mv.numpy()[:, ~sky].T
    assert np.abs(q[:, :2] - want).max() < 2e-3
    # sky: a direction, moved by the camera rotation only
    d_world = (inv[:3, :3] @ view[sky].T).T
    dv = np.asarray(prev.camera.world_to_camera)[:3, :3] @ d_world.T
    clip = np.asarray(prev.camera.projection)[:, :3] @ dv
    qs = np.stack([(clip[0] / clip[3] + 1) / 2 * W, (1 - clip[1] / clip[3]) / 2 * H], 1)
    want = np.stack([xs.numpy()[sky], ys.numpy()[sky]], 1) + cur.mv.numpy()[:, sky].T
    assert np.abs(qs - want).max() < 2e-3


def test_no_prev_time_means_zero_vectors():
    f = render(scene("blade"), 3.0, None)
    assert torch.count_nonzero(f.mv) == 0


def test_buffers_are_well_formed():
    for seed in range(6):
        sc = load_scene(random_scene(seed, size=(48, 32), effects=[
            "shadows", "specular", "reflection", "translucency", "texture_animation"]))
        f = render(sc, 2.5, 2.0)
        hit = torch.isfinite(f.depth[0])
        assert torch.isfinite(f.color).all() and (f.color >= 0).all()
        assert torch.isfinite(f.mv).all()
        assert (f.depth[0][hit] > 0).all() and (torch.isinf(f.depth[0][~hit])).all()
        n = f.normal.norm(dim=0)
        assert torch.allclose(n[hit], torch.ones_like(n[hit]), atol=1e-4)
        assert (f.alpha >= 0).all() and (f.alpha <= 1).all()
        assert f.camera is not None and f.time == 2.5


def test_ground_truth_lies_between_its_neighbours():
    """The thrown ball's and the crossing ball's projected centre, and the centroid of their
    pixels, at t + 1/2 lie between those at t and t + 1."""
    for name, obj in (("throw", "ball"), ("blade", "ball")):
        sc = scene(name)
        k = sc.object_index(obj)
        for i in (2, 9):
            cen, proj = [], []
            for t in (i, i + 0.5, i + 1):
                ex = {}
                render(sc, t, None, extras=ex)
                ys, xs = torch.nonzero(ex["object_id"] == k, as_tuple=True)
                assert len(xs) > 4, (name, t)
                cen.append(np.array([xs.float().mean() + 0.5, ys.float().mean() + 0.5]))
                proj.append(sc.project(sc.object_center(obj, t), t))
            for pts, tol in ((proj, 1e-6), (cen, 1.0)):
                a, m, b = pts
                assert np.all(m >= np.minimum(a, b) - tol) and np.all(m <= np.maximum(a, b) + tol)
                assert np.linalg.norm(b - a) > 1.0  # it moves
                # the mid-time position is near the middle (motion is smooth over a frame)
                assert np.linalg.norm(m - (a + b) / 2) < 0.25 * np.linalg.norm(b - a) + tol


# ----------------------------------------------------------------------------- work counting

def _stats(d, effects, **kw):
    sc = load_scene(dict(d, effects=effects), size=(64, 40), **kw)
    sc.reset_stats()
    render(sc, 3.0, 2.0)
    return dict(sc.stats)


def test_effects_off_cost_nothing():
    d = scene_dict("throw")  # shadows, specular, a mirror panel (reflection)
    base = _stats(d, [])
    assert base["primary_rays"] == 64 * 40 * (16 + 1)  # 4x4 samples + the G-buffer ray
    assert base.get("shadow_rays", 0) == 0 and base.get("reflection_rays", 0) == 0
    sh = _stats(d, ["shadows"])
    assert sh["shadow_rays"] > 0 and sh.get("reflection_rays", 0) == 0
    assert sh["primitive_tests"] > base["primitive_tests"]
    rf = _stats(d, ["reflection"])
    assert rf["reflection_rays"] > 0 and rf.get("shadow_rays", 0) == 0
    assert rf["primitive_tests"] > base["primitive_tests"]
    # the same scene with both: exactly the sum of the extra work
    both = _stats(d, ["shadows", "reflection"])
    assert both["shadow_rays"] == sh["shadow_rays"]
    assert both["reflection_rays"] == rf["reflection_rays"]
    # translucency: the glass pane of `blade` is opaque and untraced without the effect
    b = scene_dict("blade")
    assert _stats(b, []).get("translucent_rays", 0) == 0
    assert _stats(b, ["translucency"])["translucent_rays"] > 0


def test_culling_changes_work_not_pixels(monkeypatch):
    sc = scene("orbit", size=(64, 40))
    monkeypatch.setattr(tracer, "MAX_RAYS", 4096)  # many row bands
    out = {}
    for cull in (True, False):
        monkeypatch.setattr(tracer, "CULL", cull)
        sc.reset_stats()
        out[cull] = (render(sc, 5.0, 4.0), sc.stats["primitive_tests"])
    (a, na), (b, nb) = out[True], out[False]
    for f in ("color", "depth", "mv", "normal", "albedo", "roughness", "alpha"):
        assert torch.equal(getattr(a, f), getattr(b, f)), f
    assert na < 0.8 * nb


# ----------------------------------------------------------------------------- effects

def _with(d, effects, **extra):
    d = dict(d, effects=effects, **extra)
    return load_scene(d, size=(64, 40))


def test_overlays_have_no_depth_or_vectors():
    d = scene_dict("orbit")
    plain = render(_with(d, []), 4.0, 3.0)
    for eff in ("particles", "hud"):
        f = render(_with(d, [eff]), 4.0, 3.0)
        assert not torch.equal(f.color, plain.color), eff
        for fld in ("depth", "mv", "normal", "albedo", "alpha"):
            assert torch.equal(getattr(f, fld), getattr(plain, fld)), (eff, fld)
    # the HUD is static: the same pixels at two times on a static view
    d_static = dict(scene_dict("shadows"), lights=[])
    a = render(_with(d_static, ["hud"]), 1.0)
    b = render(_with(d_static, ["hud"]), 7.0)
    assert torch.equal(a.color, b.color)
    # particles move between frames on that same static view
    a = render(_with(d_static, ["particles"]), 1.0)
    b = render(_with(d_static, ["particles"]), 7.0)
    assert not torch.equal(a.color, b.color)


def test_texture_animation_moves_shading_not_geometry():
    d = scene_dict("shadows")
    d["lights"] = d["lights"][1:]  # static light only
    d["objects"][0]["texture"]["scroll"] = [0.5, 0.2]
    still = _with(d, [])
    anim = _with(d, ["texture_animation"])
    a1, a2 = render(anim, 2.0, 1.0), render(anim, 5.0, 4.0)
    s1 = render(still, 2.0, 1.0)
    assert torch.equal(a1.depth, s1.depth) and torch.equal(a1.mv, s1.mv)
    assert not torch.equal(a1.albedo, a2.albedo)
    assert torch.equal(s1.albedo, render(still, 5.0, 4.0).albedo)


def test_translucent_layer_keeps_the_opaque_buffers():
    d = scene_dict("blade")
    off = _with(d, [])
    ex = {}
    render(off, 3.0, 2.0, extras=ex)
    glass = ex["object_id"] == off.object_index("glass")
    assert glass.any()  # without the effect the pane is an opaque surface
    # with it, the pixels behind the pane keep the depth and vectors of what is behind
    a = render(_with(d, ["translucency"]), 3.0, 2.0)
    ref = dict(d, objects=[o for o in d["objects"] if o.get("name") != "glass"])
    c = render(_with(ref, []), 3.0, 2.0)
    assert torch.equal(a.depth, c.depth) and torch.equal(a.mv, c.mv)
    assert not torch.equal(a.color[:, glass], c.color[:, glass])


def test_overscan_and_jitter_inputs():
    d = scene_dict("orbit")
    base = _with(d, [])
    over = load_scene(dict(d, effects=["overscan"], overscan_pixels=6), size=(64, 40))
    f = render(over, 3.0, 2.0, role="input")
    assert f.color.shape == (3, 52, 76)
    g = render(base, 3.0, 2.0, role="input")
    inner = f.color[:, 6:-6, 6:-6]
    assert (inner - g.color).abs().max() < 1e-3
    assert (f.mv[:, 6:-6, 6:-6] - g.mv).abs().max() < 1e-3
    # ground truth is the nominal frame
    assert render(over, 3.5, 3.0, role="gt").color.shape == (3, 40, 64)
    jit = _with(d, ["jitter"])
    fj = [render(jit, t, t - 1, role="input") for t in (1.0, 2.0)]
    assert fj[0].color.shape == (3, 20, 32)
    cams = [tracer.frame_camera(jit, t, "input") for t in (1.0, 2.0)]
    assert cams[0].jitter != cams[1].jitter
    assert all(abs(j) <= 0.5 for c in cams for j in c.jitter)
    assert render(jit, 1.5, 1.0, role="gt").color.shape == (3, 40, 64)


def test_random_scenes_are_reproducible_and_varied():
    assert random_scene(3) == random_scene(3)
    kinds = {load_scene(random_scene(s)).camera.kind for s in range(30)}
    assert len(kinds) >= 4
    shapes = {o.shape for s in range(10) for o in load_scene(random_scene(s)).objects}
    assert shapes == {"plane", "box", "sphere", "cylinder"}
    with pytest.raises(ValueError):
        random_scene(0, effects=["sparkles"])


# ----------------------------------------------------------------------------- sequences

def test_schedule_timeline():
    sc = scene("orbit", frames=3)
    jobs = schedule(sc, 2)
    assert [(r, n) for r, n, _, _ in jobs] == [
        ("input", 0), ("gt", 1), ("input", 2), ("gt", 3), ("input", 4), ("gt", 5)]
    assert [(t, p) for _, _, t, p in jobs] == [
        (0, -1), (0.5, 0), (1, 0), (1.5, 1), (2, 1), (2.5, 2)]
    jobs3 = schedule(sc, 3)
    gt = [(n, t, p) for r, n, t, p in jobs3 if r == "gt"]
    assert gt[:2] == [(1, 1 / 3, 0.0), (2, 2 / 3, 1 / 3)]
    assert [n for r, n, _, _ in jobs3 if r == "input"] == [0, 3, 6]
    assert [n for r, n, _, _ in schedule(sc, None)] == [0, 1, 2]


def test_render_sequence_writes_the_fgen_layout(tmp_path):
    from fgcli.io.reader import SequenceReader

    sc = scene("throw", size=(48, 32), frames=3, spp=2)
    res = render_sequence(sc, tmp_path / "in", gt_dir=tmp_path / "gt", gt_factor=2,
                          progress=False)
    assert (res["input"], res["gt"]) == (3, 3)
    assert sorted(os.listdir(tmp_path / "in")) == [
        "cameras.json", "throw.0000.exr", "throw.0002.exr", "throw.0004.exr"]
    assert sorted(os.listdir(tmp_path / "gt"))[1:] == [
        "throw.0001.exr", "throw.0003.exr", "throw.0005.exr"]
    r = SequenceReader(str(tmp_path / "in"))
    assert r.numbers == [0, 2, 4] and r.step == 2
    f = r.read(2)
    ref = render(sc, 1.0, 0.0, spp=2)
    assert torch.equal(f.depth, ref.depth)
    assert (f.mv - ref.mv).abs().max() <= 2.0 ** -11  # rounded to 1/1024 pixel
    assert torch.equal(f.mv, torch.round(f.mv * 1024) / 1024)
    assert torch.allclose(f.color, ref.color, rtol=2e-3, atol=1e-3)
    assert f.camera is not None
    assert np.allclose(f.camera.world_to_camera, ref.camera.world_to_camera, atol=1e-6)
    a = read_header(str(tmp_path / "gt" / "throw.0003.exr")).attributes
    assert a["fgen:synth_scene"] == "throw" and a["fgen:synth_role"] == "gt"
    assert a["fgen:time"] == pytest.approx(1.5) and a["fgen:mv_time"] == pytest.approx(1.0)
    cams = json.loads((tmp_path / "gt" / "cameras.json").read_text())
    assert [e["frame"] for e in cams["frames"]] == [1, 3, 5]


def test_two_renders_are_byte_identical(tmp_path):
    sc = scene("blade", size=(40, 24), frames=2, spp=2)
    for k in ("a", "b"):
        render_sequence(sc, tmp_path / k / "in", gt_dir=tmp_path / k / "gt", progress=False)
    for sub in ("in", "gt"):
        names = sorted(os.listdir(tmp_path / "a" / sub))
        assert names == sorted(os.listdir(tmp_path / "b" / sub))
        for n in names:
            a = (tmp_path / "a" / sub / n).read_bytes()
            b = (tmp_path / "b" / sub / n).read_bytes()
            assert a == b, n  # byte-identical: the writer adds no time stamp


def test_overscan_is_written_as_a_data_window(tmp_path):
    d = dict(scene_dict("orbit"), effects=["overscan"], overscan_pixels=4, frames=2)
    sc = load_scene(d, size=(32, 20), spp=1)
    render_sequence(sc, tmp_path / "in", progress=False)
    h = read_header(str(tmp_path / "in" / "scene.0001.exr"))
    p = h.parts[0]
    assert (p.width, p.height) == (32, 20)
    assert (p.x, p.y, p.data_width, p.data_height) == (-4, -4, 40, 28)
    assert h.attributes["fgen:overscan"] == 4


# ----------------------------------------------------------------------------- CLI

def test_cli_synth(tmp_path):
    run = CliRunner().invoke
    scene_file = os.path.join(SCENES, "shadows.toml")
    out, gt = tmp_path / "out", tmp_path / "gt"
    args = ["synth", scene_file, str(out), "--size", "32x20", "--frames", "2", "--spp", "1",
            "--gt", str(gt), "--gt-factor", "3", "--no-progress"]
    r = run(cli, args)
    assert r.exit_code == 0, r.output
    assert sorted(os.listdir(out)) == ["cameras.json", "shadows.0000.exr", "shadows.0003.exr"]
    assert len(os.listdir(gt)) == 5  # 1, 2, 4, 5 and cameras.json
    r = run(cli, args)  # refuses a non-empty folder
    assert r.exit_code == 3 and "not empty" in r.output
    r = run(cli, args[:3] + ["--size", "32x20", "--frames", "1", "--spp", "1", "--overwrite",
                             "--no-progress"])
    assert r.exit_code == 0, r.output
    assert sorted(os.listdir(out)) == ["cameras.json", "shadows.0000.exr"]  # stale ones gone
    bad = tmp_path / "bad.toml"
    bad.write_text('[camera]\ntype = "orbit"\nradius = -1\n[[objects]]\ntype = "sphere"\n')
    r = run(cli, ["synth", str(bad), str(tmp_path / "x")])
    assert r.exit_code == 1 and "bad.toml" in r.output and "camera.radius" in r.output
    r = run(cli, ["synth", scene_file])
    assert r.exit_code == 2
    r = run(cli, ["synth", scene_file, str(tmp_path / "y"), "--size", "big"])
    assert r.exit_code == 2
    png = tmp_path / "sheet.png"
    r = run(cli, ["synth", "--preview", str(png), scene_file, os.path.join(SCENES, "blade.toml"),
                  "--size", "48x27", "--spp", "1"])
    assert r.exit_code == 0, r.output
    import cv2

    img = cv2.imread(str(png))
    assert img.shape[0] > 2 * 27 and img.shape[1] > 5 * 48


# ----------------------------------------------------------------------------- sample data

@pytest.mark.parametrize("name", NAMES)
def test_shipped_sample_data(name):
    """Every scene ships its input (0, 2, ..., 32), its half-resolution jittered input
    (lowres: 0, 2, ..., 32; lowres_gbuffer: the same with every odd input frame
    G-buffer-only) and ground truth (0, 1, ..., 33: the in-between and after frames, and
    the full-resolution frame at every input time), and the files are what the scene file
    renders today."""
    from fgcli.synth.scene import load_scene as _load

    base = os.path.join(SAMPLES, name)
    inp = sorted(f for f in os.listdir(os.path.join(base, "input")) if f.endswith(".exr"))
    gt = sorted(f for f in os.listdir(os.path.join(base, "gt")) if f.endswith(".exr"))
    assert inp == [f"{name}.{n:04d}.exr" for n in range(0, 33, 2)]
    assert gt == [f"{name}.{n:04d}.exr" for n in range(0, 34)]
    jit = _load(os.path.join(SCENES, f"{name}.toml"), add_effects=("jitter",))
    for sub in ("lowres", "lowres_gbuffer"):
        low = sorted(f for f in os.listdir(os.path.join(base, sub)) if f.endswith(".exr"))
        assert low == inp
        for n in (0, 2, 4):
            h = read_header(os.path.join(base, sub, f"{name}.{n:04d}.exr"))
            assert (h.width, h.height) == (128, 72)
            assert h.attributes["fgen:synth_hash"] == jit.hash
            assert "fgen:jitter_x" in h.attributes and "fgen:jitter_y" in h.attributes
            names = {c for _, c, _ in h.all_channels()}
            shaded = sub == "lowres" or n % 4 == 0
            assert ("R" in names) == shaded and {"Z", "mv.x", "N.x", "albedo.R"} <= names
    for sub in ("input", "gt", "lowres", "lowres_gbuffer"):
        assert os.path.isfile(os.path.join(base, sub, "cameras.json"))
    sc = load_scene(os.path.join(SCENES, f"{name}.toml"))
    path = os.path.join(base, "gt", f"{name}.0013.exr")
    h = read_header(path)
    assert (h.width, h.height) == (256, 144)
    assert h.attributes["fgen:synth_hash"] == sc.hash
    ref = render(sc, 6.5, 6.0)
    ch = read_channels(path, [(0, c) for c in ("R", "G", "B", "Z", "mv.x", "mv.y")], h)
    # Stored floats against floats computed now, on whatever CPU runs the test: torch picks
    # other vector kernels on other CPUs (AVX-512 / AVX2 / default), so float32 results differ
    # in the last bits. Tolerances, from float32 rounding (eps = 2**-23 = 1.19e-7):
    # - depth is stored as float32; a ray-surface intersection is ~10 dependent float32
    #   operations, each off by <= 0.5 ulp when the kernel reassociates, so 16 ulp relative
    #   (rtol 2e-6) bounds it with margin; sky (inf) must stay inf.
    # - color is stored as half (rel. step 2**-11 = 4.9e-4) after averaging 16 samples;
    #   2e-3 of the frame's range is 4 half steps.
    # - vectors are rounded to 1/1024 px when written; 1e-3 px is one rounding step.
    # A pixel whose primary ray grazes a silhouette may hit the other surface after a 1-ulp
    # change; such flips are allowed on at most 0.05% of pixels (18 of 36864) and nowhere else.
    color = np.stack([ch[(0, c)] for c in "RGB"])
    depth = ch[(0, "Z")]
    mv = np.stack([ch[(0, "mv.x")], ch[(0, "mv.y")]])
    ref_depth = ref.depth[0].numpy()
    assert np.array_equal(np.isinf(depth), np.isinf(ref_depth))
    ok = np.isclose(depth, ref_depth, rtol=2e-6, atol=0.0)
    ok &= (np.abs(color - ref.color.numpy()) <= 2e-3 * max(1.0, float(ref.color.max()))).all(0)
    ok &= (np.abs(mv - ref.mv.numpy()) <= 1e-3).all(0)
    assert (~ok).sum() <= 0.0005 * ok.size, f"{(~ok).sum()} pixels differ beyond float32 rounding"


@pytest.mark.slow
@pytest.mark.parametrize("name", NAMES)
def test_backward_warp_on_shipped_frames(name):
    """The shipped input frames (vectors rounded to 1/1024 px, color in half floats) pass
    the same warp check at full size; the mask comes from re-rendering with extras."""
    from fgcli.io.reader import SequenceReader

    sc = load_scene(os.path.join(SCENES, f"{name}.toml"))
    seq = SequenceReader(os.path.join(SAMPLES, name, "input"))
    for i in (3, 12):
        prev, cur = seq.read(2 * (i - 1)), seq.read(2 * i)
        pe, ce = {}, {}
        render(sc, i - 1, i - 2, extras=pe, role="input")
        render(sc, i, i - 1, extras=ce, role="input")
        valid = warp_valid(cur.mv, ce, pe)
        assert psnr(backward_warp(prev.color, cur.mv), cur.color, valid) > 35.0
