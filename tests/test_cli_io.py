"""fgen info / convert, and bad input through the command line (issue #2 items 7 and 8).

Every failure: a documented exit code, one message on stderr naming the file (and frame),
no Python traceback unless --debug."""
from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest
import torch

from fgcli.errors import EXIT_BAD_INPUT, EXIT_OUTPUT, EXIT_USAGE
from fgcli.frame import Frame
from fgcli.io import exr, layouts
from fgcli.io.frames import write_frame
from fgcli.io.reader import SequenceReader

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


from tests._cli import fgen  # noqa: E402


def scene_seq(folder, tiny_scene, n=3, layout="fgen", start=1, name="shot.{:04d}.exr",
              size=None, **kw):
    os.makedirs(folder, exist_ok=True)
    for t in range(n):
        s = tiny_scene(t, *(size or ()))
        f = Frame(number=start + t, color=torch.from_numpy(s["color"]),
                  depth=torch.from_numpy(s["depth"]), mv=torch.from_numpy(s["mv"]),
                  mv_fwd=torch.from_numpy(s["mv_fwd"]), **kw)
        write_frame(os.path.join(folder, name.format(start + t)), f, layout=layout)
    return str(folder)


def rgb_file(path, s, extra=None, types=None):
    ch = {"R": s["color"][0], "G": s["color"][1], "B": s["color"][2], **(extra or {})}
    exr.write_exr(str(path), ch, types)


# ------------------------------------------------------------------------------------ info

def test_info_json(tmp_path, tiny_scene, capsys):
    d = scene_seq(tmp_path / "in", tiny_scene, n=3, start=1001)
    code, out, err = fgen(capsys, "info", d, "--json")
    assert code == 0
    j = json.loads(out)
    for k in ("layout", "width", "height", "frames", "channels", "has_camera"):
        assert k in j
    assert j["layout"] == "fgen" and (j["width"], j["height"]) == (32, 24)
    assert j["frames"] == [1001, 1002, 1003] and j["has_camera"] is False
    types = {c["name"]: c["type"] for c in j["channels"]}
    assert types["R"] == "half" and types["mv.x"] == "float" and types["Z"] == "float"
    assert "nonfinite" not in j


def test_info_text_and_scan(tmp_path, tiny_scene, capsys):
    d = tmp_path / "in"
    d.mkdir()
    for t in (1, 2, 3):
        s = tiny_scene(t)
        c = s["color"].copy()
        if t == 2:
            c[0, 0, :3] = np.nan
        rgb_file(d / f"x.{t:04d}.exr", {"color": c},
                 {"Z": s["depth"][0], "mv.x": s["mv"][0], "mv.y": s["mv"][1]},
                 {"R": "float", "Z": "float", "mv.x": "float", "mv.y": "float"})
    code, out, _ = fgen(capsys, "info", d)
    assert code == 0
    assert "layout:      fgen (detected)" in out and "32x24" in out and "1-3 (3 frames" in out
    assert "cameras:     none" in out and "NaN/Inf" not in out
    code, out, _ = fgen(capsys, "info", d, "--scan")
    assert "R " in out and "3 (frames 2)" in out
    code, out, _ = fgen(capsys, "info", d, "--scan", "--json")
    j = json.loads(out)
    assert j["nonfinite"]["R"] == {"count": 3, "frames": [2]}
    assert j["nonfinite"]["Z"]["count"] == 0  # +inf sky is not counted for depth


def test_info_says_vectors_derived_and_views(tmp_path, tiny_scene, capsys):
    d = tmp_path / "nk"
    d.mkdir()
    for t in (1, 2):
        s = tiny_scene(t)
        ch = {"R": s["color"][0], "G": s["color"][1], "B": s["color"][2],
              "forward.u": s["mv_fwd"][0], "forward.v": -s["mv_fwd"][1],
              "right.R": s["color"][0], "right.G": s["color"][1], "right.B": s["color"][2],
              "forward.right.u": s["mv_fwd"][0], "forward.right.v": -s["mv_fwd"][1]}
        exr.write_exr(str(d / f"n.{t:04d}.exr"), ch, None, {"multiView": ["left", "right"]})
    code, out, _ = fgen(capsys, "info", d)
    assert code == 0 and "layout:      nuke" in out
    assert "backward vectors derived from forward vectors" in out
    assert "view:        left (views: left, right)" in out
    code, out, _ = fgen(capsys, "info", d, "--json", "--view", "right")
    j = json.loads(out)
    assert j["view"] == "right" and j["mv_derived"] and j["mv_source"] == "forward"
    code, _, err = fgen(capsys, "info", d, "--view", "centre")
    assert code == EXIT_BAD_INPUT and "views: left, right" in err


def test_info_and_help_do_not_import_torch(tmp_path, tiny_scene):
    d = tmp_path / "in"
    d.mkdir()
    rgb_file(d / "a.0001.exr", tiny_scene(0))
    code = ("import sys\nfrom fgcli.cli import main\n"
            "try:\n    main(sys.argv[1:])\nexcept SystemExit as e:\n    rc = e.code\n"
            "print('TORCH' if 'torch' in sys.modules else 'NO-TORCH', rc)\n")
    for args in (["--help"], ["info", str(d), "--json", "--scan"], ["convert", "--help"]):
        r = subprocess.run([sys.executable, "-c", code, *args], capture_output=True,
                           text=True, cwd=ROOT, timeout=60)
        assert r.stdout.strip().endswith("NO-TORCH 0"), (args, r.stdout, r.stderr)


# --------------------------------------------------------------------------------- convert

def test_convert_round_trip_through_layouts(tmp_path, tiny_scene, capsys):
    d = scene_seq(tmp_path / "in", tiny_scene, n=2)
    for lay in ("blender", "nuke"):
        code, out, err = fgen(capsys, "convert", d, tmp_path / lay, "--out-layout", lay)
        assert code == 0 and f"converted 2 frames from fgen to {lay}" in out
        assert SequenceReader(str(tmp_path / lay)).layout.name == lay
        code, out, _ = fgen(capsys, "convert", tmp_path / lay, tmp_path / (lay + "-back"))
        assert code == 0
        for n in (1, 2):
            a = SequenceReader(d).read(n)
            b = SequenceReader(str(tmp_path / (lay + "-back"))).read(n)
            fin = torch.isfinite(a.depth[0])
            assert torch.equal(a.mv[:, fin], b.mv[:, fin])
            assert torch.equal(a.depth, b.depth)
            assert torch.allclose(a.color, b.color, rtol=2 ** -10)
            h = exr.read_header(os.path.join(tmp_path / (lay + "-back"), f"shot.{n:04d}.exr"))
            assert h.attributes["fgen:converted_from"] == lay
            assert h.attributes["fgen:source_frames"] == str(n)


def test_convert_no_clobber_overwrite_resume(tmp_path, tiny_scene, capsys):
    d = scene_seq(tmp_path / "in", tiny_scene, n=2)
    out = tmp_path / "out"
    assert fgen(capsys, "convert", d, out)[0] == 0
    code, _, err = fgen(capsys, "convert", d, out)
    assert code == EXIT_OUTPUT and "shot.0001.exr" in err and "--overwrite" in err
    os.remove(out / "shot.0002.exr")
    code, so, _ = fgen(capsys, "convert", d, out, "--resume")
    assert code == 0 and "converted 1 frames" in so and "skipped 1 complete" in so
    mtime = os.stat(out / "shot.0001.exr").st_mtime_ns
    code, so, _ = fgen(capsys, "convert", d, out, "--overwrite", "--float",
                       "--compression", "piz")
    assert code == 0 and "converted 2 frames" in so
    h = exr.read_header(str(out / "shot.0001.exr"))
    assert set(h.parts[0].formats) == {"float"} and h.attributes["compression"] == "piz"
    assert os.stat(out / "shot.0001.exr").st_mtime_ns >= mtime
    assert not [f for f in os.listdir(out) if f.startswith(".fgen-tmp-")]


def test_convert_toml_layout_and_input_out_layout(tmp_path, tiny_scene, capsys):
    d = tmp_path / "in"
    d.mkdir()
    for t in (1, 2):
        s = tiny_scene(t)
        exr.write_exr(str(d / f"u.{t:04d}.exr"),
                      {"beauty.R": s["color"][0], "beauty.G": s["color"][1],
                       "beauty.B": s["color"][2], "motion.x": s["mv"][0] / 32,
                       "motion.y": -s["mv"][1] / 24})
    toml = tmp_path / "mine.toml"
    toml.write_text('name = "mine"\n[channels]\ncolor = ["beauty.R","beauty.G","beauty.B"]\n'
                    'mv = ["motion.x", "motion.y"]\n[conventions]\nmv_units = "uv"\n'
                    'mv_y = "up"\n')
    code, _, err = fgen(capsys, "convert", d, tmp_path / "o")
    assert code == EXIT_BAD_INPUT and "cannot detect the layout" in err
    code, so, _ = fgen(capsys, "convert", d, tmp_path / "o", "--layout", toml)
    assert code == 0 and "from mine to fgen" in so
    f = SequenceReader(str(tmp_path / "o")).read(2)
    assert torch.allclose(f.mv, torch.from_numpy(tiny_scene(2)["mv"]), atol=1e-3)
    code, so, _ = fgen(capsys, "convert", d, tmp_path / "o2", "--layout", toml,
                       "--out-layout", "input")
    assert code == 0 and "from mine to mine" in so
    assert "motion.x" in exr.read_header(str(tmp_path / "o2" / "u.0001.exr")).parts[0].channels


# ------------------------------------------------------------------------------- bad input

def test_truncated_file(tmp_path, tiny_scene, capsys):
    d = scene_seq(tmp_path / "in", tiny_scene, n=3)
    p = os.path.join(d, "shot.0002.exr")
    data = open(p, "rb").read()
    open(p, "wb").write(data[: len(data) // 2])
    code, _, err = fgen(capsys, "convert", d, tmp_path / "out")
    assert code == EXIT_BAD_INPUT
    assert "shot.0002.exr" in err and "frame 2" in err and "truncated or corrupt" in err
    code, _, err = fgen(capsys, "info", d, "--scan")
    assert code == EXIT_BAD_INPUT and "frame 2" in err
    open(p, "wb").write(data[:100])  # header cut short
    code, _, err = fgen(capsys, "info", d)
    assert code == EXIT_BAD_INPUT and "shot.0002.exr" in err and "frame 2" in err


def test_not_an_exr(tmp_path, tiny_scene, capsys):
    d = scene_seq(tmp_path / "in", tiny_scene, n=2)
    open(os.path.join(d, "shot.0003.exr"), "w").write("this is not an image\n")
    code, _, err = fgen(capsys, "info", d)
    assert code == EXIT_BAD_INPUT
    assert "shot.0003.exr" in err and "frame 3" in err and "not an OpenEXR file" in err


def test_missing_required_channels(tmp_path, tiny_scene, capsys):
    d = tmp_path / "in"
    d.mkdir()
    s = tiny_scene(0)
    exr.write_exr(str(d / "y.0001.exr"), {"Y": s["color"][0], "Z": s["depth"][0]})
    code, _, err = fgen(capsys, "info", d)
    assert code == EXIT_BAD_INPUT
    assert "cannot detect the layout from channels Y, Z" in err
    assert "tried: fgen, blender, nuke" in err
    code, _, err = fgen(capsys, "convert", d, tmp_path / "o", "--layout", "fgen")
    assert code == EXIT_BAD_INPUT
    assert "missing channels for color" in err and "layout 'fgen'" in err
    assert "channels found: Y, Z" in err and "y.0001.exr" in err and "frame 1" in err
    # a pipeline asking for vectors the file lacks
    rgb_file(d / "y.0001.exr", s)
    r = SequenceReader(str(d), fields={"color", "depth", "mv"})
    with pytest.raises(Exception) as e:
        r.read(1)
    assert "missing channels for depth" in str(e.value) and "found: B, G, R" in str(e.value)


def test_frames_of_different_sizes(tmp_path, tiny_scene, capsys):
    d = tmp_path / "in"
    d.mkdir()
    rgb_file(d / "s.0001.exr", tiny_scene(0))
    rgb_file(d / "s.0002.exr", tiny_scene(1, 20, 30))
    code, _, err = fgen(capsys, "info", d)
    assert code == EXIT_BAD_INPUT
    assert "s.0002.exr" in err and "frame 2" in err and "30x20 differs" in err
    code, _, err = fgen(capsys, "convert", d, tmp_path / "o")
    assert code == EXIT_BAD_INPUT and "frame 2" in err


def test_nan_inf_counted_replaced_one_warning(tmp_path, tiny_scene, capsys):
    d = tmp_path / "in"
    d.mkdir()
    for t in (1, 2, 3):
        s = tiny_scene(t)
        c, mv = s["color"].copy(), s["mv"].copy()
        if t in (1, 3):
            c[1, 2, 2] = np.inf
        if t == 3:
            mv[0, 5, 5] = np.nan
        rgb_file(d / f"s.{t:04d}.exr", {"color": c},
                 {"Z": s["depth"][0], "mv.x": mv[0], "mv.y": mv[1]},
                 {k: "float" for k in ("R", "G", "B", "Z", "mv.x", "mv.y")})
    code, so, err = fgen(capsys, "convert", d, tmp_path / "o")
    assert code == 0
    warnings = [ln for ln in err.splitlines() if ln.startswith("warning:")]
    assert len(warnings) == 1
    w = warnings[0]
    assert "frames 1, 3" in w and "color: 2" in w and "mv: 1" in w and "(frames 3)" in w
    r = SequenceReader(str(tmp_path / "o"))
    for n in (1, 2, 3):
        f = r.read(n)
        assert torch.isfinite(f.color).all() and torch.isfinite(f.mv).all()
    assert not r.read(3).mv_valid[0, 5, 5]  # the replaced vector stays flagged


def test_empty_folder(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    code, _, err = fgen(capsys, "info", tmp_path / "empty")
    assert code == EXIT_BAD_INPUT and "no EXR frames found" in err and "empty" in err
    code, _, err = fgen(capsys, "convert", tmp_path / "empty", tmp_path / "o")
    assert code == EXIT_BAD_INPUT


def test_unwritable_output_and_input_folder(tmp_path, tiny_scene, capsys):
    d = scene_seq(tmp_path / "in", tiny_scene, n=1)
    (tmp_path / "file").write_text("x")
    code, _, err = fgen(capsys, "convert", d, tmp_path / "file" / "out")
    assert code == EXIT_OUTPUT and "cannot create output folder" in err
    code, _, err = fgen(capsys, "convert", d, d)
    assert code == EXIT_OUTPUT and "input folder" in err


def test_usage_errors(tmp_path, tiny_scene, capsys):
    d = scene_seq(tmp_path / "in", tiny_scene, n=2)
    code, _, err = fgen(capsys, "info", d, "--layout", "maya")
    assert code == EXIT_USAGE and "unknown layout 'maya'" in err
    code, _, err = fgen(capsys, "info", d, "--frames", "1..2")
    assert code == EXIT_USAGE and "bad frame range" in err
    code, _, err = fgen(capsys, "convert", d, tmp_path / "o", "--compression", "lzw")
    assert code == EXIT_USAGE


def test_debug_shows_traceback(tmp_path):
    (tmp_path / "empty").mkdir()
    r = subprocess.run([sys.executable, "-m", "fgcli", "info", str(tmp_path / "empty")],
                       capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert r.returncode == EXIT_BAD_INPUT and "Traceback" not in r.stderr
    assert "no EXR frames found" in r.stderr and r.stdout == ""
    r = subprocess.run([sys.executable, "-m", "fgcli", "--debug", "info",
                        str(tmp_path / "empty")], capture_output=True, text=True, cwd=ROOT,
                       timeout=60)
    assert r.returncode != 0 and "Traceback" in r.stderr


def test_layout_registry_names():
    assert set(layouts.LAYOUTS) == {"fgen", "blender", "nuke"}
