"""Sky vectors from the cameras: Blender writes 0 for sky pixels even when the camera turns;
the reader flags them and, with cameras known, recomputes them (points at infinity)."""
from __future__ import annotations

import os

import numpy as np
import torch

from fgcli.io import exr, layouts
from fgcli.io.cameras import sky_motion
from fgcli.io.frames import write_sidecar_cameras
from fgcli.io.reader import SequenceReader
from fgcli.synth import load_scene, render

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _orbit(size=(64, 36)):
    return load_scene(os.path.join(ROOT, "sample_data", "scenes", "orbit.toml"), size=size,
                      spp=1)


def test_sky_motion_matches_the_renderers_analytic_vectors():
    sc = _orbit()
    f0, f1 = render(sc, 2.0, 1.0), render(sc, 3.0, 2.0)
    sky = ~torch.isfinite(f1.depth[0])
    assert sky.sum() > 100 and f1.mv[:, sky].abs().max() > 1.0  # the sky does move
    mv = sky_motion(f1.camera, f0.camera, 64, 36)
    assert np.abs(mv[:, sky.numpy()] - f1.mv[:, sky].numpy()).max() < 1e-3
    assert np.abs(sky_motion(f1.camera, f1.camera, 64, 36)).max() < 1e-6  # same camera


def test_blender_sky_vectors_are_filled_from_cameras(tmp_path):
    sc = _orbit()
    frames = [render(sc, float(t), float(t - 1)) for t in range(3)]
    for f in frames:
        chans, types = layouts.encode(f, "blender")
        vec = [k for k in chans if k.endswith(".Vector.X") or k.endswith(".Vector.Y")]
        sky = ~np.isfinite(f.depth[0].numpy())
        for k in vec:  # as Blender does: zero vectors on the sky
            chans[k] = np.where(sky, 0.0, chans[k])
        exr.write_exr(str(tmp_path / f"shot.{f.number:04d}.exr"), chans, types)
    write_sidecar_cameras(str(tmp_path), {f.number: f.camera for f in frames})
    r = SequenceReader(str(tmp_path))
    assert r.layout.name == "blender"
    g = r.read(2)
    sky = ~torch.isfinite(g.depth[0])
    assert torch.allclose(g.mv[:, sky], frames[2].mv[:, sky], atol=1e-3)
    assert g.mv_valid is None or bool(g.mv_valid[0][sky].all())
    assert any("sky vectors" in n for n in r.notes)
    # without cameras the vectors stay flagged, not trusted
    os.remove(tmp_path / "cameras.json")
    g2 = SequenceReader(str(tmp_path)).read(2)
    assert g2.mv_valid is not None and not bool(g2.mv_valid[0][sky].any())
