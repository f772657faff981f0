"""Layouts: fgen, blender, nuke, multi-view, user TOML, auto-detection (issue #2 item 4)."""
from __future__ import annotations

import os

import numpy as np
import pytest
import torch

from fgcli.errors import InputError, UsageError
from fgcli.frame import Frame
from fgcli.io import exr, layouts
from fgcli.io.frames import read_frame, write_frame
from fgcli.io.reader import SequenceReader

BL = "ViewLayer."


# ------------------------------------------------------------------------------- writers

def scene_frame(s: dict, t: int, **drop) -> Frame:
    kw = {k: torch.from_numpy(s[k]) for k in ("color", "depth", "mv", "normal", "albedo",
                                              "roughness") if not drop.get(k)}
    return Frame(number=t, **kw)


def blender_channels(s: dict, prefix: str = BL) -> tuple[dict, dict]:
    """Hand-written Blender Cycles conventions (shared/ALGORITHMS.md): Vector Y up,
    backward = (X, -Y), forward = (-Z, W); sky: vectors 0, depth 1e10, normal 0."""
    sky = np.isinf(s["depth"][0])
    z = lambda a: np.where(sky, 0.0, a)  # noqa: E731
    ch = {
        "Combined.R": s["color"][0], "Combined.G": s["color"][1], "Combined.B": s["color"][2],
        "Combined.A": np.ones_like(s["color"][0]),
        "Depth.Z": np.where(sky, 1e10, s["depth"][0]),
        "Vector.X": z(s["mv"][0]), "Vector.Y": z(-s["mv"][1]),
        "Vector.Z": z(-s["mv_fwd"][0]), "Vector.W": z(s["mv_fwd"][1]),
        "Normal.X": s["normal"][0], "Normal.Y": s["normal"][1], "Normal.Z": s["normal"][2],
        "DiffCol.R": s["albedo"][0], "DiffCol.G": s["albedo"][1], "DiffCol.B": s["albedo"][2],
        "roughness.X": s["roughness"][0],
    }
    types = {k: ("half" if k.startswith(("Combined", "DiffCol")) else "float") for k in ch}
    return {prefix + k: v for k, v in ch.items()}, {prefix + k: v for k, v in types.items()}


def nuke_channels(s: dict, backward=True, forward=True, depth="depth.Z", view_prefix=None):
    """Nuke conventions: u = +x, v = +y up (pixels)."""
    ch = {"R": s["color"][0], "G": s["color"][1], "B": s["color"][2], depth: s["depth"][0]}
    if backward:
        ch["backward.u"], ch["backward.v"] = s["mv"][0], -s["mv"][1]
    if forward:
        ch["forward.u"], ch["forward.v"] = s["mv_fwd"][0], -s["mv_fwd"][1]
    types = {k: ("half" if k in "RGB" else "float") for k in ch}
    return ch, types


def write_seq(folder, n, make, name="shot.{:04d}.exr", start=1):
    os.makedirs(folder, exist_ok=True)
    for t in range(n):
        ch, ty = make(t)
        exr.write_exr(os.path.join(folder, name.format(start + t)), ch, ty)
    return str(folder)


def warp_back(prev: np.ndarray, mv: np.ndarray) -> np.ndarray:
    """Bilinear backward warp: out(p) = prev(p + mv(p)), pixel centres at +0.5."""
    c, h, w = prev.shape
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    sx, sy = x + mv[0], y + mv[1]
    x0, y0 = np.floor(sx).astype(int), np.floor(sy).astype(int)
    fx, fy = sx - x0, sy - y0
    out = np.zeros_like(prev, dtype=np.float64)
    for dy, wy in ((0, 1 - fy), (1, fy)):
        for dx, wx in ((0, 1 - fx), (1, fx)):
            xi, yi = np.clip(x0 + dx, 0, w - 1), np.clip(y0 + dy, 0, h - 1)
            out += prev[:, yi, xi] * (wx * wy)
    return out


# ------------------------------------------------------------------------------------ fgen

def test_fgen_round_trip_exact_float_and_half_color(tmp_path, tiny_scene):
    s = tiny_scene(2)
    f = scene_frame(s, 2)
    f.alpha = torch.full((1, 24, 32), 0.5)
    p = str(tmp_path / "a.0002.exr")
    write_frame(p, f)  # half color by default
    g = read_frame(p, 2)
    assert g.mv.dtype == torch.float32 and torch.equal(g.mv, f.mv)  # float channels exact
    assert torch.equal(g.depth, f.depth)  # inf survives
    assert torch.allclose(g.color, f.color, rtol=2 ** -10, atol=0)  # half precision
    assert torch.equal(g.alpha, f.alpha)
    assert torch.allclose(g.normal, f.normal, rtol=2 ** -10, atol=1e-4)
    # all float: exact everywhere
    write_frame(p, f, half=False)
    g = read_frame(p, 2)
    for k in ("color", "normal", "albedo", "roughness", "mv", "depth"):
        assert torch.equal(getattr(g, k), getattr(f, k)), k
    h = exr.read_header(p)
    assert set(h.parts[0].formats) == {"float"}


def test_fgen_write_types_half_color_float_vectors(tmp_path, tiny_scene):
    p = str(tmp_path / "a.0001.exr")
    write_frame(p, scene_frame(tiny_scene(1), 1))
    part = exr.read_header(p).parts[0]
    t = dict(zip(part.channels, part.formats))
    assert t["R"] == "half" and t["Z"] == "float" and t["mv.x"] == "float"
    assert t["mv.y"] == "float" and t["albedo.R"] == "half"


def test_fgen_mv_valid_channel_round_trip(tmp_path, tiny_scene):
    s = tiny_scene(1)
    f = scene_frame(s, 1)
    valid = torch.ones(1, 24, 32, dtype=torch.bool)
    valid[0, :3] = False
    f.mv_valid = valid
    p = str(tmp_path / "v.0001.exr")
    write_frame(p, f)
    assert "mv.valid" in exr.read_header(p).parts[0].channels
    g = read_frame(p, 1)
    assert torch.equal(g.mv_valid, valid)
    # all valid: no channel written, mv_valid None
    f.mv_valid = torch.ones_like(valid)
    write_frame(p, f)
    assert "mv.valid" not in exr.read_header(p).parts[0].channels
    assert read_frame(p, 1).mv_valid is None


# --------------------------------------------------------------------------------- blender

def test_blender_conventions(tmp_path, tiny_scene):
    s = tiny_scene(2)
    d = write_seq(tmp_path / "bl", 1, lambda t: blender_channels(s), start=2)
    r = SequenceReader(d)
    assert r.layout.name == "blender"
    f = r.read(2)
    sky = np.isinf(s["depth"][0])
    assert torch.isinf(f.depth[0][torch.from_numpy(sky)]).all()  # 1e10 -> +inf
    assert torch.equal(f.depth[0][~torch.from_numpy(sky)],
                       torch.from_numpy(s["depth"][0][~sky]))
    # Y up -> y down; sky vectors flagged
    assert torch.equal(f.mv[:, ~torch.from_numpy(sky)], torch.from_numpy(s["mv"][:, ~sky]))
    assert f.mv_valid is not None
    assert torch.equal(f.mv_valid[0], torch.from_numpy(~sky))
    assert torch.allclose(f.albedo, torch.from_numpy(s["albedo"]), atol=1e-3)
    assert torch.equal(f.roughness, torch.from_numpy(s["roughness"]))
    assert torch.equal(f.normal, torch.from_numpy(s["normal"]))
    # fields=None reads everything, forward vectors (-Z, W) included
    assert torch.equal(f.mv_fwd[:, ~torch.from_numpy(sky)],
                       torch.from_numpy(s["mv_fwd"][:, ~sky]))
    g = SequenceReader(d, fields={"color", "mv"}).read(2)
    assert g.mv_fwd is None and g.normal is None  # only what was asked for
    assert g.depth is None  # depth read for the sky test only, not handed out
    assert torch.equal(g.mv_valid, f.mv_valid)


def test_blender_converted_mv_satisfy_internal_convention(tmp_path, tiny_scene):
    """Done criterion: Blender -> fgen; warping t-1 by t's mv reproduces t far better than
    no warp on non-sky, non-disoccluded pixels."""
    d = write_seq(tmp_path / "bl", 3, lambda t: blender_channels(tiny_scene(t)), start=0)
    from fgcli.cli import main

    with pytest.raises(SystemExit) as e:
        main(["convert", d, str(tmp_path / "fg"), "--float"])
    assert e.value.code == 0
    r = SequenceReader(str(tmp_path / "fg"))
    assert r.layout.name == "fgen"
    for t in (1, 2):
        prev, cur = r.read(t - 1), r.read(t)
        s_prev, s_cur = tiny_scene(t - 1), tiny_scene(t)
        mv = cur.mv.numpy()
        warped = warp_back(prev.color.numpy(), mv)
        h, w = s_cur["ids"].shape
        y, x = np.mgrid[0:h, 0:w]
        px = np.clip(np.round(x + mv[0]).astype(int), 0, w - 1)
        py = np.clip(np.round(y + mv[1]).astype(int), 0, h - 1)
        inside = (x + mv[0] >= 0) & (x + mv[0] <= w - 1) & (y + mv[1] >= 0) & (y + mv[1] <= h - 1)
        same = s_prev["ids"][py, px] == s_cur["ids"]
        m = (s_cur["ids"] > 0) & same & inside
        assert m.sum() > 0.5 * m.size
        err_warp = np.abs(warped - cur.color.numpy())[:, m].mean()
        err_none = np.abs(prev.color.numpy() - cur.color.numpy())[:, m].mean()
        assert err_warp < 0.05 * err_none, (err_warp, err_none)
        # sky flag survives the conversion (mv.valid channel)
        assert cur.mv_valid is not None and not cur.mv_valid[0, 0, 0]


def test_fgen_blender_fgen_round_trip(tmp_path, tiny_scene):
    s = tiny_scene(3)
    f = scene_frame(s, 3)
    p1, p2 = str(tmp_path / "b.0003.exr"), str(tmp_path / "c.0003.exr")
    write_frame(p1, f, layout="blender")
    h = exr.read_header(p1)
    assert "ViewLayer.Vector.W" in h.parts[0].channels
    assert h.parts[0].format_of("ViewLayer.Normal.X") == "float"
    g = read_frame(p1, 3)
    assert layouts.resolve(None, h).name == "blender"
    write_frame(p2, g, layout="fgen")
    k = read_frame(p2, 3)
    fin = torch.isfinite(f.depth[0])
    assert torch.equal(k.mv[:, fin], f.mv[:, fin])
    assert torch.equal(k.depth, f.depth)
    assert torch.allclose(k.color, f.color, rtol=2 ** -10)


def test_blender_roughness_aov_any_case_and_view_layer_name(tmp_path, tiny_scene):
    s = tiny_scene(0)
    ch, ty = blender_channels(s, prefix="RenderLayer.")
    ch["RenderLayer.Roughness.X"] = ch.pop("RenderLayer.roughness.X")
    ty["RenderLayer.Roughness.X"] = ty.pop("RenderLayer.roughness.X")
    p = str(tmp_path / "x.0000.exr")
    exr.write_exr(p, ch, ty)
    f = read_frame(p, 0)
    assert torch.equal(f.roughness, torch.from_numpy(s["roughness"]))


# ------------------------------------------------------------------------------------ nuke

def test_nuke_backward_vectors_v_up(tmp_path, tiny_scene):
    s = tiny_scene(1)
    p = str(tmp_path / "n.0001.exr")
    exr.write_exr(p, *nuke_channels(s, depth="Z"))
    f = read_frame(p, 1, fields={"color", "depth", "mv", "mv_fwd"})
    assert torch.equal(f.mv, torch.from_numpy(s["mv"]))
    assert torch.equal(f.mv_fwd, torch.from_numpy(s["mv_fwd"]))
    assert torch.equal(f.depth, torch.from_numpy(s["depth"]))


def test_nuke_forward_only_derives_backward(tmp_path, tiny_scene):
    d = write_seq(tmp_path / "nk", 4, lambda t: nuke_channels(tiny_scene(t), backward=False))
    r = SequenceReader(d, fields={"color", "depth", "mv"})
    assert r.layout.name == "nuke" and r.mv_derived
    assert any("derived from forward" in n for n in r.notes)
    first = r.read(1)
    assert first.mv is not None and not first.mv_valid.any()  # nothing to derive from
    for n in (2, 3, 4):
        f = r.read(n)
        s = tiny_scene(n - 1)
        valid = f.mv_valid[0].numpy() if f.mv_valid is not None else np.ones((24, 32), bool)
        truth = s["mv"]
        nonsky = s["ids"] > 0
        good = valid & nonsky
        assert good.mean() > 0.6
        assert np.array_equal(f.mv.numpy()[:, good], truth[:, good])
        assert np.isfinite(f.mv.numpy()).all()
        assert f.mv_fwd is None  # helper only


def test_nuke_forward_only_with_frame_selection_uses_disk_neighbour(tmp_path, tiny_scene):
    d = write_seq(tmp_path / "nk", 4, lambda t: nuke_channels(tiny_scene(t), backward=False))
    r = SequenceReader(d, frames="2-4x2", fields={"color", "mv"})
    f = r.read(4)  # derived from frame 3 on disk, then chained through it to frame 2
    s = tiny_scene(4)
    good = f.mv_valid[0].numpy() & (s["ids"] > 0)
    assert good.mean() > 0.6
    # the vectors span the selected 2-frame gap: twice the constant per-frame motion,
    # exactly, away from the pixels whose surface changed in between (silhouettes)
    exact = (np.abs(f.mv.numpy() - 2 * s["mv"]) < 1e-5).all(0) & good
    assert exact.sum() > 0.6 * good.sum()


def test_fgen_nuke_fgen_round_trip(tmp_path, tiny_scene):
    s = tiny_scene(2)
    f = scene_frame(s, 2)
    f.mv_fwd = torch.from_numpy(s["mv_fwd"])
    p = str(tmp_path / "n.0002.exr")
    write_frame(p, f, layout="nuke")
    ch = exr.read_header(p).parts[0].channels
    assert {"backward.u", "backward.v", "forward.u", "forward.v", "depth.Z"} <= set(ch)
    g = read_frame(p, 2, fields={"color", "depth", "mv", "mv_fwd"})
    assert torch.equal(g.mv, f.mv) and torch.equal(g.mv_fwd, f.mv_fwd)
    assert torch.equal(g.depth, f.depth)


# ------------------------------------------------------------------------------ multi-view

def _stereo_single_part(s_left, s_right):
    """Default view 'left' unprefixed, 'right' prefixed (OpenEXR multi-view naming)."""
    ch, ty = nuke_channels(s_left)
    rch, rty = nuke_channels(s_right)

    def pre(k):
        parts = k.split(".")
        return ".".join(parts[:-1] + ["right", parts[-1]])

    ch.update({pre(k): v for k, v in rch.items()})
    ty.update({pre(k): v for k, v in rty.items()})
    return ch, ty


def test_stereo_single_part_views(tmp_path, tiny_scene):
    sl, sr = tiny_scene(1), tiny_scene(3)
    ch, ty = _stereo_single_part(sl, sr)
    assert "forward.right.u" in ch and "right.R" in ch
    p = str(tmp_path / "st.0001.exr")
    exr.write_exr(p, ch, ty, {"multiView": ["left", "right"]})
    h = exr.read_header(p)
    assert layouts.views(h) == ["left", "right"]
    assert layouts.resolve(None, h).name == "nuke"
    left = read_frame(p, 1)
    right = read_frame(p, 1, view="right")
    assert torch.equal(left.mv, torch.from_numpy(sl["mv"]))
    assert torch.equal(right.mv, torch.from_numpy(sr["mv"]))
    assert torch.equal(right.depth, torch.from_numpy(sr["depth"]))
    with pytest.raises(InputError, match="views: left, right"):
        read_frame(p, 1, view="middle")


def test_stereo_multi_part_views(tmp_path, tiny_scene):
    sl, sr = tiny_scene(1), tiny_scene(2)
    parts = []
    for view, s in (("left", sl), ("right", sr)):
        ch, ty = nuke_channels(s)
        parts.append(dict(channels=ch, types=ty, name=f"rgba.{view}", view=view,
                          attributes={"multiView": ["left", "right"]}))
    p = str(tmp_path / "mp.0001.exr")
    exr.write_parts(p, parts)
    h = exr.read_header(p)
    assert len(h.parts) == 2 and [x.view for x in h.parts] == ["left", "right"]
    r = SequenceReader(str(tmp_path), view="right", fields={"color", "mv", "depth"})
    assert r.view == "right" and r.views == ["left", "right"]
    f = r.read(1)
    assert torch.equal(f.mv, torch.from_numpy(sr["mv"]))
    assert torch.allclose(f.color, torch.from_numpy(sr["color"]), rtol=2 ** -10)
    assert torch.equal(read_frame(p, 1).mv, torch.from_numpy(sl["mv"]))  # default = first


def test_multi_part_layers_tiled_data_window_mixed_types(tmp_path, tiny_scene):
    """One part per layer, tiled, the vector part's data window smaller than the display
    window: padded, and vectors outside it flagged invalid."""
    s = tiny_scene(1)
    rgb = {"R": s["color"][0], "G": s["color"][1], "B": s["color"][2], "Z": s["depth"][0]}
    vec = {"mv.x": s["mv"][0][2:20, 3:30], "mv.y": s["mv"][1][2:20, 3:30]}
    p = str(tmp_path / "m.0001.exr")
    exr.write_parts(p, [
        dict(channels=rgb, types={"R": "half", "G": "half", "B": "half", "Z": "float"},
             name="rgba"),
        dict(channels=vec, types={"mv.x": "float", "mv.y": "half"}, name="vectors",
             data_window=(3, 2, 27, 18), display=(32, 24)),
    ], tile=16)
    h = exr.read_header(p)
    assert all(part.tiled for part in h.parts)
    assert not h.parts[1].full_data_window
    f = read_frame(p, 1)
    assert layouts.resolve(None, h).name == "fgen"
    assert f.mv.shape == (2, 24, 32)
    inside = np.zeros((24, 32), bool)
    inside[2:20, 3:30] = True
    assert torch.equal(f.mv[:, torch.from_numpy(inside)],
                       torch.from_numpy(s["mv"][:, inside]))
    assert (f.mv[:, torch.from_numpy(~inside)] == 0).all()
    assert torch.equal(f.mv_valid[0], torch.from_numpy(inside))


# -------------------------------------------------------------------------------- TOML

TOML = """
name = "studio"
[channels]
color = ["beauty.R", "beauty.G", "beauty.B"]
depth = "invz.X"
mv = ["vel.X", "vel.Y"]
[conventions]
mv_y = "up"
mv_units = "ndc"
mv_sign = -1
depth_kind = "inverse"
"""


def test_toml_user_layout(tmp_path, tiny_scene):
    s = tiny_scene(2)
    h, w = 24, 32
    # Unreal-like: screen-space [-1, 1], y up, current minus previous; depth stored as 1/z
    vel_x = -s["mv"][0] / (w / 2)
    vel_y = s["mv"][1] / (h / 2)
    with np.errstate(divide="ignore"):
        invz = np.where(np.isinf(s["depth"][0]), 0.0, 1.0 / s["depth"][0])
    ch = {"beauty.R": s["color"][0], "beauty.G": s["color"][1], "beauty.B": s["color"][2],
          "invz.X": invz, "vel.X": vel_x, "vel.Y": vel_y}
    p = str(tmp_path / "u.0002.exr")
    exr.write_exr(p, ch, {k: "float" for k in ch})
    lp = tmp_path / "studio.toml"
    lp.write_text(TOML)
    with pytest.raises(InputError, match="cannot detect the layout"):
        read_frame(p, 2)
    f = read_frame(p, 2, layout=str(lp))
    assert torch.allclose(f.mv, torch.from_numpy(s["mv"]), atol=1e-5)
    assert torch.allclose(f.depth, torch.from_numpy(s["depth"]), rtol=1e-6)
    # and back out through the same mapping
    q = str(tmp_path / "v.0002.exr")
    write_frame(q, f, layout=str(lp), half=False)
    g = read_frame(q, 2, layout=str(lp))
    assert torch.allclose(g.mv, f.mv, atol=1e-5) and torch.allclose(g.depth, f.depth)


@pytest.mark.parametrize("text,match", [
    ("[channels]\ncolor = ['R','G','B']\nbogus = 'x'\n", "unknown key"),
    ("[channels]\ncolor = ['R','G']\n", "needs 3 channel"),
    ("[channels]\ndepth = 'Z'\n", "color"),
    ("[channels]\ncolor = ['R','G','B']\n[conventions]\nmv_units = 'furlongs'\n", "mv_units"),
    ("[channels]\ncolor = ['R','G','B']\n[conventions]\nmv_y = 'left'\n", "mv_y"),
    ("not toml = = =", "bad layout TOML"),
])
def test_toml_errors(tmp_path, text, match):
    p = tmp_path / "bad.toml"
    p.write_text(text)
    with pytest.raises(UsageError, match=match):
        layouts.get(str(p))


# ------------------------------------------------------------------- detection and errors

def test_auto_detection_and_override(tmp_path, tiny_scene):
    s = tiny_scene(1)
    cases = {
        "fgen": ({"R": s["color"][0], "G": s["color"][1], "B": s["color"][2],
                  "mv.x": s["mv"][0], "mv.y": s["mv"][1]}, None),
        "nuke": nuke_channels(s),
        "blender": blender_channels(s),
    }
    for name, (ch, ty) in cases.items():
        p = str(tmp_path / f"{name}.0001.exr")
        exr.write_exr(p, ch, ty)
        assert layouts.resolve(None, exr.read_header(p)).name == name
    # override: a nuke file read as fgen (color only -> works, mv missing -> error)
    p = str(tmp_path / "nuke.0001.exr")
    assert layouts.resolve("fgen", exr.read_header(p)).name == "fgen"
    with pytest.raises(UsageError, match="unknown layout"):
        layouts.get("maya")


def test_missing_required_channels_lists_found_and_layout(tmp_path, tiny_scene):
    s = tiny_scene(1)
    p = str(tmp_path / "c.0001.exr")
    exr.write_exr(p, {"R": s["color"][0], "G": s["color"][1], "B": s["color"][2]})
    with pytest.raises(InputError) as e:
        read_frame(p, 1, fields={"color", "mv"})
    msg = str(e.value.message)
    assert "layout 'fgen'" in msg and "mv.x, mv.y" in msg and "found: B, G, R" in msg
    assert p in msg and "frame 1" in msg
    # optional fields may be absent
    f = read_frame(p, 1, fields={"color"})
    assert f.mv is None and f.alpha is None


def test_reads_only_needed_channels(tmp_path, tiny_scene, monkeypatch):
    s = tiny_scene(1)
    ch, ty = blender_channels(s)
    p = str(tmp_path / "b.0001.exr")
    exr.write_exr(p, ch, ty)
    seen = []
    orig = exr.read_channels

    def spy(path, wanted, header=None, fill=None):
        seen.extend(n for _, n in wanted)
        return orig(path, wanted, header, fill)

    monkeypatch.setattr(exr, "read_channels", spy)
    read_frame(p, 1, fields={"color"})
    assert set(seen) == {BL + "Combined." + c for c in "RGBA"}
    seen.clear()
    read_frame(p, 1, fields={"color", "mv"})
    assert BL + "Vector.X" in seen and BL + "Depth.Z" in seen  # depth for the sky flag
    assert BL + "Normal.X" not in seen and BL + "Vector.Z" not in seen


def test_nonfinite_replaced_and_counted(tmp_path, tiny_scene):
    s = tiny_scene(1)
    c = s["color"].copy()
    c[0, 0, 0] = np.nan
    c[1, 1, 1] = np.inf
    mv = s["mv"].copy()
    mv[0, 5, 5] = -np.inf
    d = s["depth"].copy()
    d[0, 10, 10] = np.nan
    ch = {"R": c[0], "G": c[1], "B": c[2], "Z": d[0], "mv.x": mv[0], "mv.y": mv[1]}
    p = str(tmp_path / "n.0001.exr")
    exr.write_exr(p, ch, {k: "float" for k in ch})
    stats = {}
    f = layouts.get("fgen").read(exr.read_header(p), 1, nonfinite=stats)
    assert torch.isfinite(f.color).all() and torch.isfinite(f.mv).all()
    assert f.depth[0, 10, 10] == np.inf
    assert not f.mv_valid[0, 5, 5] and f.mv_valid.sum() == 24 * 32 - 1
    assert stats == {"color": [(1, 2)], "mv": [(1, 1)], "depth": [(1, 1)]}


def test_normals_in_camera_space_converted_to_world(tmp_path, tiny_scene):
    from fgcli.frame import Camera
    from fgcli.io import cameras

    s = tiny_scene(0)
    ang = np.pi / 2  # camera yawed 90 degrees about +Y
    rot = np.array([[np.cos(ang), 0, -np.sin(ang), 0], [0, 1, 0, 0],
                    [np.sin(ang), 0, np.cos(ang), 0], [0, 0, 0, 1]])
    cam = Camera(rot, np.diag([1.0, 1.0, -1.0, 0.0]) + np.array(
        [[0, 0, 0, 0], [0, 0, 0, 0], [0, 0, 0, -0.2], [0, 0, -1, 0]]))
    n_cam = np.zeros((3, 24, 32), np.float32)
    n_cam[2] = 1.0  # facing the camera
    ch = {"R": s["color"][0], "G": s["color"][1], "B": s["color"][2],
          "n.x": n_cam[0], "n.y": n_cam[1], "n.z": n_cam[2]}
    p = str(tmp_path / "n.0000.exr")
    exr.write_exr(p, ch, {k: "float" for k in ch}, cameras.header_attributes(cam),
                  attribute_types=cameras.CAMERA_ATTRIBUTE_TYPES)
    lp = tmp_path / "n.toml"
    lp.write_text('[channels]\ncolor=["R","G","B"]\nnormal=["n.x","n.y","n.z"]\n'
                  '[conventions]\nnormal_space="camera"\n')
    f = read_frame(p, 0, layout=str(lp))
    expect = rot[:3, :3].T @ np.array([0, 0, 1.0])
    assert np.allclose(f.normal[:, 3, 3].numpy(), expect, atol=1e-6)


def test_frames_without_backward_vectors_are_told_and_not_used(tmp_path, tiny_scene):
    """Forward-only files: the first frame on disk has nothing to derive backward vectors
    from. fgen info and the run log name it and say what the pipeline does there; the
    pipeline never reads its zero vectors as motion (linear motion from the next frame)."""
    from click.testing import CliRunner

    from fgcli.cli import cli
    from fgcli.runner import make_ctx

    d = write_seq(tmp_path / "nk", 3, lambda t: nuke_channels(tiny_scene(t), backward=False))
    r = SequenceReader(d)
    assert r.frames_without_backward() == [r.numbers[0]]
    f0, f1 = r.read(r.numbers[0]), r.read(r.numbers[1])
    ctx = make_ctx(f0, f1, 0.5, "interp")
    assert ctx["mv0"] is None and ctx["mv1"] is not None
    res = CliRunner().invoke(cli, ["info", d])
    assert res.exit_code == 0 and f"no backward vectors: frames {r.numbers[0]}" in res.output
    res = CliRunner().invoke(cli, ["interpolate", d, str(tmp_path / "o"), "--no-progress"])
    assert res.exit_code == 0, res.output
    assert f"frames {r.numbers[0]} of" in res.output and "linear motion" in res.output
    full = SequenceReader(write_seq(tmp_path / "nb", 3, lambda t: nuke_channels(tiny_scene(t))))
    assert full.frames_without_backward() == []
