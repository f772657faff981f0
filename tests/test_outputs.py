"""Generated frames say what they are (issue 61, item 1): their own time, the camera at that
time and alpha, checked against the renderer's ground truth (fgcli.synth renders any time),
for interpolation and extrapolation, with --emit all too; `fgen info` shows fgen's
metadata."""
from __future__ import annotations

import json
import os

import numpy as np
import pytest

from fgcli.io.reader import SequenceReader

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ORBIT = os.path.join(ROOT, "sample_data", "scenes", "orbit.toml")


from tests._cli import fgen  # noqa: E402


@pytest.fixture(scope="module")
def orbit(tmp_path_factory):
    """The bundled orbit scene, tiny: input frames 0, 2, .., 8 and ground truth between
    and after them (frames 1, 3, .., 9) at 1 sample per pixel."""
    from fgcli.synth.scene import load_scene
    from fgcli.synth.sequence import render_sequence

    root = tmp_path_factory.mktemp("orbit")
    scene = load_scene(ORBIT, size=(48, 28), frames=5, spp=1)
    render_sequence(scene, str(root / "input"), str(root / "gt"), gt_factor=2,
                    progress=False)
    return root


def _attrs(path):
    from fgcli.io import exr

    return exr.read_header(path).attributes


def _check_against_gt(out_dir, gt_dir, numbers, camera=True, alpha_tol=0.02):
    """Each output frame n against ground-truth frame n: fgen:time and fgen:time_seconds
    (float32 in the synth's headers: 1e-6), the camera (float64 JSON matrices; the rigid
    interpolation of an orbit is exact to rounding: 1e-6), alpha (mean |error|: alpha is
    coverage, 0 on sky: 0.25 of this frame; a warp misses only the edges of what enters or
    leaves, ~0.005)."""
    out = SequenceReader(str(out_dir), fields={"color"})
    gt = SequenceReader(str(gt_dir), fields={"color"})
    for n in numbers:
        a, g = _attrs(out.path(n)), _attrs(gt.path(n))
        assert float(a["fgen:time"]) == pytest.approx(float(g["fgen:time"]), abs=1e-6), n
        assert float(a["fgen:time_seconds"]) == pytest.approx(float(g["fgen:time_seconds"]),
                                                             abs=1e-6), n
        assert int(a["fgen:frame"]) == n
        assert "fgen:synth_role" not in a  # the source's role is not this frame's
        fo, fg = out.read(n), gt.read(n)
        assert fo.alpha is not None and fg.alpha is not None, n
        err = float((fo.alpha - fg.alpha).abs().mean())
        assert err < alpha_tol, (n, err)
        if camera:
            assert fo.camera is not None, n
            np.testing.assert_allclose(fo.camera.world_to_camera, fg.camera.world_to_camera,
                                       atol=1e-6, err_msg=f"frame {n}")
            np.testing.assert_allclose(fo.camera.projection, fg.camera.projection, atol=1e-6)
            # the OpenEXR standard attributes too (what other tools read)
            assert "worldToCamera" in a and "worldToNDC" in a


def test_interpolated_frames_time_camera_alpha(orbit, tmp_path, capsys):
    out = tmp_path / "i"
    code, _, err = fgen(capsys, "interpolate", orbit / "input", out, "--pipeline", "mob-fgsr",
                        "--backend", "torch", "--no-progress", "--emit", "all")
    assert code == 0, err
    _check_against_gt(out, orbit / "gt", [1, 3, 5, 7])
    for n in (0, 2, 8):  # rendered frames copied through keep their own header
        a = _attrs(SequenceReader(str(out)).path(n))
        assert a["fgen:synth_role"] == "input" and int(a["fgen:rendered"]) == 1
        assert float(a["fgen:time"]) == n / 2
    g = _attrs(SequenceReader(str(out)).path(3))
    assert g["fgen:source_synth_role"] == "input" and g["fgen:source_frames"] == "2,4"
    assert float(g["fgen:input_frame"]) == 3.0
    # alpha of a generated frame is not a copy of either source's
    fo = SequenceReader(str(out)).read(3)
    src = SequenceReader(str(orbit / "input")).read(2)
    assert not np.array_equal(fo.alpha.numpy(), src.alpha.numpy())


def test_extrapolated_frames_time_camera_alpha(orbit, tmp_path, capsys):
    out = tmp_path / "x"
    code, _, err = fgen(capsys, "extrapolate", orbit / "input", out, "--pipeline",
                        "mob-fgsr", "--alpha", "0.5", "--backend", "torch", "--no-progress",
                        "--emit", "all", "--out-layout", "input")
    assert code == 0, err
    # frame 1 has no history: its camera is frame 0's (as gffe-extrap's), not the truth
    _check_against_gt(out, orbit / "gt", [1], camera=False)
    _check_against_gt(out, orbit / "gt", [3, 5, 7, 9])
    # extrapolating from fgen's own output keeps the camera gffe-extrap needs
    out2 = tmp_path / "x2"
    code, _, err = fgen(capsys, "extrapolate", out, out2, "--pipeline", "gffe-extrap",
                        "--alpha", "0.5", "--backend", "torch", "--no-progress",
                        "--frames", "5-9")
    assert code == 0, err


def test_info_shows_fgen_metadata(orbit, capsys):
    code, out, _ = fgen(capsys, "info", orbit / "gt", "--json")
    assert code == 0
    meta = json.loads(out)["fgen"]
    assert meta["synth_role"] == "gt" and "time" in meta and "time_seconds" in meta
    assert len(meta["world_to_camera"]) == 4
    code, out, _ = fgen(capsys, "info", orbit / "gt")
    assert "fgen:synth_role" in out and "fgen:time" in out


def test_camera_interpolation_is_exact_on_an_orbit_and_hits_its_ends():
    from fgcli.frame import Camera
    from fgcli.io.metadata import interpolate_camera
    from fgcli.ops.gffe import look_at

    proj0, proj1 = np.diag([1.2, 2.0, -1.0, 0.0]), np.diag([1.4, 2.2, -1.0, 0.0])

    def cam(deg, proj):
        a = np.radians(deg)
        pos = np.array([5 * np.sin(a), 1.5, 5 * np.cos(a)])
        return Camera(look_at(pos, -pos + [0, 0.5, 0], [0, 1, 0]), proj)

    c0, c1 = cam(10, proj0), cam(50, proj1)
    for t, ref in ((0.0, c0), (1.0, c1)):
        c = interpolate_camera(c0, c1, t)
        np.testing.assert_allclose(c.world_to_camera, ref.world_to_camera, atol=1e-12)
        np.testing.assert_allclose(c.projection, ref.projection, atol=1e-12)
    mid = interpolate_camera(c0, c1, 0.25)
    np.testing.assert_allclose(mid.world_to_camera, cam(20, proj0).world_to_camera, atol=1e-9)
    np.testing.assert_allclose(mid.projection, 0.75 * proj0 + 0.25 * proj1)
    assert interpolate_camera(None, c1, 0.5) is None


def test_time_from_two_sources_one_source_or_none():
    from fgcli.io.metadata import time_attributes

    h0 = {"fgen:time": 0.0, "fgen:time_seconds": 0.0, "fgen:frame_rate": 60.0}
    h1 = {"fgen:time": 1.0, "fgen:time_seconds": 1 / 30, "fgen:frame_rate": 60.0}
    d = time_attributes([(0, h0), (2, h1)], 1.0, 1, "scaled", 1)
    assert d["fgen:time"] == 0.5 and d["fgen:time_seconds"] == pytest.approx(1 / 60)
    # extrapolated past the only source: seconds by the frame rate, time by the vectors' span
    h1m = {**h1, "fgen:mv_time": 0.0}
    d = time_attributes([(2, h1m)], 3.0, 3, "scaled", 1, step=2)
    assert d["fgen:time"] == 1.5 and d["fgen:time_seconds"] == pytest.approx(1 / 30 + 1 / 60)
    # no time in the sources: the place on the input timeline; a scaled rate
    d = time_attributes([(0, {}), (1, {"fgen:frame_rate": 24.0})], 0.5, 1, "scaled", 2)
    assert d["fgen:time"] == 0.5 and "fgen:time_seconds" not in d
    assert d["fgen:frame_rate"] == 48.0 and d["fgen:input_frame"] == 0.5
