"""Cameras (issue #2 item 5): OpenEXR worldToCamera/worldToNDC, sidecar cameras.json,
the fgen header, and the Blender export script."""
from __future__ import annotations

import importlib.util
import json
import os

import numpy as np
import pytest

from fgcli.errors import InputError
from fgcli.frame import Camera
from fgcli.io import cameras, exr, layouts
from fgcli.io.frames import load_sidecar_cameras, read_frame, write_frame, write_sidecar_cameras
from fgcli.io.reader import SequenceReader

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
W, H = 64, 48
C = np.array([1.0, 2.0, 5.0])  # camera position, looking down world -Z, +Y up


def exr_matrices():
    """A RenderMan-style camera written as OpenEXR attributes, from first principles:
    camera space x right, y up, +z forward (left-handed); row vectors; 90 degree horizontal
    field of view; NDC (0,0) top-left, (1,1) bottom-right."""
    m = np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, -1, 0], [-C[0], -C[1], C[2], 1.0]])
    q = np.zeros((4, 4))
    q[:, 0] = [0.5, 0, 0.5, 0]  # x_ndc = (x/z + 1) / 2
    q[:, 1] = [0, -0.5 * W / H, 0.5, 0]  # y_ndc = (1 - (y/z) * W/H) / 2
    q[:, 2] = [0, 0, 1, 0]
    q[:, 3] = [0, 0, 1, 0]  # w = z
    return m, m @ q


def expected_pixel(p):
    x, y, z = p[0] - C[0], p[1] - C[1], -(p[2] - C[2])  # RenderMan camera space
    return np.array([(x / z + 1) / 2 * W, (1 - y / z * W / H) / 2 * H, z])


POINTS = np.array([[1.0, 2.0, 0.0], [3.0, 1.0, -2.0], [-2.0, 4.0, -7.0], [1.5, 2.5, 1.0]])


def test_from_exr_known_camera():
    m, n = exr_matrices()
    cam = cameras.from_exr(m.ravel(), n.ravel())
    # OpenGL view matrix: translation by -C, no rotation; points in front have z < 0
    assert np.allclose(cam.world_to_camera, [[1, 0, 0, -1], [0, 1, 0, -2], [0, 0, 1, -5],
                                             [0, 0, 0, 1]])
    assert np.allclose(cam.projection[0], [1, 0, 0, 0])  # cot(45 deg)
    assert np.allclose(cam.projection[1], [0, W / H, 0, 0])
    assert np.allclose(cam.projection[3], [0, 0, -1, 0])
    got = cameras.project(cam, POINTS, W, H)
    want = np.stack([expected_pixel(p) for p in POINTS])
    assert np.allclose(got, want, atol=1e-9)
    # NDC depth inside [-1, 1] between near and far
    v = cam.world_to_camera @ np.r_[POINTS[1], 1]
    c = cam.projection @ v
    assert -1 < c[2] / c[3] < 1


def test_exr_camera_round_trip():
    m, n = exr_matrices()
    cam = cameras.from_exr(m.ravel(), n.ravel())
    m2, n2 = cameras.to_exr(cam)
    cam2 = cameras.from_exr(m2, n2)
    assert np.allclose(cam2.world_to_camera, cam.world_to_camera)
    assert np.allclose(cam2.projection, cam.projection)
    assert np.allclose(np.reshape(m2, (4, 4)), m)
    # x, y, w columns of worldToNDC survive exactly (z is not standardised)
    assert np.allclose(np.reshape(n2, (4, 4))[:, [0, 1, 3]], n[:, [0, 1, 3]])


def test_camera_from_exr_header_in_a_file(tmp_path, tiny_scene):
    m, n = exr_matrices()
    s = tiny_scene(0)
    p = str(tmp_path / "c.0001.exr")
    exr.write_exr(p, {"R": s["color"][0], "G": s["color"][1], "B": s["color"][2]}, None,
                  {"worldToCamera": list(m.ravel()), "worldToNDC": list(n.ravel()),
                   "nearClip": 0.5, "farClip": 100.0})
    h = exr.read_header(p)
    assert h.parts[0].attr_types["worldToCamera"] == "matrix"
    cam = layouts.camera_from_header(h)
    assert cam is not None
    assert np.allclose(cameras.project(cam, POINTS, W, H),
                       np.stack([expected_pixel(q) for q in POINTS]))
    # near/far from the header set the z row: NDC z = -1 at near, +1 at far
    for d, z in ((0.5, -1.0), (100.0, 1.0)):
        c = cam.projection @ np.array([0, 0, -d, 1.0])
        assert np.isclose(c[2] / c[3], z)
    r = SequenceReader(str(tmp_path))
    assert r.has_camera and r.camera_source == "worldToCamera/worldToNDC"
    assert r.read(1).camera is not None


def test_fgen_writer_stores_camera_both_ways(tmp_path, tiny_scene):
    m, n = exr_matrices()
    cam = cameras.from_exr(m.ravel(), n.ravel())
    from fgcli.frame import Frame
    import torch

    f = Frame(number=3, color=torch.from_numpy(tiny_scene(0)["color"]), camera=cam,
              header={"worldToCamera": [0.0] * 16})  # stale source camera is replaced
    p = str(tmp_path / "w.0003.exr")
    write_frame(p, f)
    attrs = exr.read_header(p).attributes
    assert "fgen:world_to_camera" in attrs and "worldToNDC" in attrs
    assert np.allclose(np.reshape(attrs["worldToCamera"], (4, 4)), m)
    g = read_frame(p, 3)
    assert np.allclose(g.camera.world_to_camera, cam.world_to_camera)
    assert np.allclose(g.camera.projection, cam.projection)
    # a frame without camera writes none, even if its source header had one
    f2 = f.replace(camera=None, header={"worldToCamera": list(m.ravel()),
                                        "worldToNDC": list(n.ravel())})
    write_frame(p, f2)
    assert read_frame(p, 3).camera is None


def test_sidecar_cameras(tmp_path, tiny_scene):
    s = tiny_scene(0)
    for t in (1, 2):
        exr.write_exr(str(tmp_path / f"s.{t:04d}.exr"),
                      {"R": s["color"][0], "G": s["color"][1], "B": s["color"][2]})
    proj = [[1, 0, 0, 0], [0, 1.3, 0, 0], [0, 0, -1.0002, -0.2], [0, 0, -1, 0]]
    doc = {"generator": "test", "frames": [
        {"frame": 1, "world_to_camera": np.eye(4).tolist(), "projection": proj, "note": "x"},
        {"frame": 2, "world_to_camera": [[1, 0, 0, -1], [0, 1, 0, 0], [0, 0, 1, 0],
                                         [0, 0, 0, 1]], "projection": proj}]}
    (tmp_path / "cameras.json").write_text(json.dumps(doc))
    cams = load_sidecar_cameras(str(tmp_path))
    assert sorted(cams) == [1, 2] and np.allclose(cams[2].world_to_camera[0, 3], -1)
    r = SequenceReader(str(tmp_path))
    assert r.has_camera and r.camera_source == "cameras.json"
    f = r.read(2)
    assert np.allclose(f.camera.projection, proj)
    # write_sidecar_cameras round trip
    out = tmp_path / "o"
    out.mkdir()
    write_sidecar_cameras(str(out), cams)
    again = load_sidecar_cameras(str(out))
    assert np.allclose(again[1].projection, cams[1].projection)


@pytest.mark.parametrize("doc", [
    "{not json",
    json.dumps({"frames": [{"frame": 1, "world_to_camera": [[1, 0], [0, 1]],
                            "projection": np.eye(4).tolist()}]}),
    json.dumps({"cams": []}),
])
def test_bad_sidecar_is_input_error(tmp_path, doc):
    (tmp_path / "cameras.json").write_text(doc)
    with pytest.raises(InputError, match="cameras.json"):
        load_sidecar_cameras(str(tmp_path))


def test_no_camera(tmp_path, tiny_scene):
    s = tiny_scene(0)
    exr.write_exr(str(tmp_path / "s.0001.exr"),
                  {"R": s["color"][0], "G": s["color"][1], "B": s["color"][2]})
    r = SequenceReader(str(tmp_path))
    assert not r.has_camera and r.read(1).camera is None


def test_blender_export_script_builds_the_sidecar_format(tmp_path):
    path = os.path.join(ROOT, "scripts", "blender_export_cameras.py")
    spec = importlib.util.spec_from_file_location("blender_export_cameras", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)  # no bpy needed to import
    w2c = np.eye(4)
    w2c[0, 3] = -2
    doc = mod.build_document([(7, w2c, np.eye(4)), (8, w2c.tolist(), np.eye(4))],
                             {"camera": "Camera"})
    mod.write_document(str(tmp_path), doc)
    cams = load_sidecar_cameras(str(tmp_path))
    assert sorted(cams) == [7, 8] and cams[7].world_to_camera[0, 3] == -2
    assert isinstance(cams[8], Camera)
    args = mod._args(["blender", "-b", "x.blend", "--python", "s.py", "--", "out",
                      "--start", "3"])
    assert args.out_dir == "out" and args.start == 3
