"""Camera cuts (docs/design.md section 5): detected, never smeared; suspicious depth warned."""
from __future__ import annotations

import os
import re

import numpy as np
import pytest
import torch
from click.testing import CliRunner

from fgcli import pipeline as pl
from fgcli.cli import cli
from fgcli.frame import Frame
from fgcli.io.frames import write_frame
from fgcli.io.reader import SequenceReader, depth_suspicion
from fgcli.ops import is_scene_change, scene_change_score
from fgcli.runner import make_ctx

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _first_frames(scene, n=2):
    r = SequenceReader(os.path.join(ROOT, "sample_data", scene, "input"))
    return [r.read(k) for k in r.numbers[:n]]


def test_score_separates_shots_from_motion():
    o0, o1 = _first_frames("orbit")
    b0, _ = _first_frames("blade")
    assert scene_change_score(o0.color, o1.color) < 0.1
    assert not is_scene_change(o0.color, o1.color)
    assert is_scene_change(o0.color, b0.color)
    assert scene_change_score(o0.color, o0.color) == pytest.approx(0.0, abs=1e-6)
    with pytest.raises(ValueError):
        scene_change_score(o0.color[:2], o1.color)


@pytest.mark.parametrize("name,mode", [(n, m) for n in pl.available() for m in pl.load(n).modes])
def test_every_pipeline_repeats_the_nearest_frame_across_a_cut(name, mode):
    a, _ = _first_frames("orbit")
    b, _ = _first_frames("throw")
    tm = pl.Timings()
    for alpha, want in ((0.25, a), (0.75, b)):
        ctx = make_ctx(a, b, alpha, mode)
        ctx = pl.run_stages(pl.load(name).build(mode), ctx, tm, label="x")
        expect = b if mode == "extrap" else want
        assert torch.equal(ctx["color"], expect.color)
        assert not ctx["mv"].any()
    assert tm.skipped and all("scene cut" in why for _, _, why in tm.skipped)


def test_depth_suspicion():
    rng = np.random.default_rng(0)
    linear = rng.uniform(1, 50, (1, 8, 8)).astype(np.float32)
    linear[0, 0, :] = np.inf
    assert depth_suspicion(linear) is None
    ndc = rng.uniform(0.95, 1.0, (1, 8, 8)).astype(np.float32)
    assert "normalized device depth" in depth_suspicion(ndc)
    rev = rng.uniform(0.0, 0.05, (1, 8, 8)).astype(np.float32)
    assert "reversed-Z" in depth_suspicion(rev)
    assert "<= 0" in depth_suspicion(np.zeros((1, 4, 4), np.float32))


def test_reader_warns_once_about_device_depth(tmp_path):
    for t in range(3):
        c = torch.rand(3, 6, 8)
        write_frame(str(tmp_path / f"d.{t:04d}.exr"),
                    Frame(number=t, color=c, depth=0.97 + 0.03 * torch.rand(1, 6, 8),
                          mv=torch.zeros(2, 6, 8)))
    r = CliRunner().invoke(cli, ["interpolate", str(tmp_path), str(tmp_path / "o"),
                                 "--no-progress"])
    assert r.exit_code == 0, r.output
    assert r.output.count("looks like normalized device depth") == 1
    assert re.search(r"d\.000(\d)\.exr: frame \1: channel depth", r.output)


# ------------------------------------------- cuts confirmed by motion (issue: false cuts)

def _write_seq(folder, frames, gains=None):
    os.makedirs(folder, exist_ok=True)
    for i, f in enumerate(frames):
        g = 1.0 if gains is None else gains[i]
        write_frame(os.path.join(folder, f"s.{i:04d}.exr"),
                    Frame(number=i, color=f.color * g, depth=f.depth, mv=f.mv, camera=f.camera))


def _run_cuts(tmp_path, folder, *extra):
    out = tmp_path / ("o-" + os.path.basename(folder))
    r = CliRunner().invoke(cli, ["interpolate", str(folder), str(out), "--no-progress", *extra])
    assert r.exit_code == 0, r.output
    import json

    return json.loads((out / "fgen-run.json").read_text())["scene_cuts"], out, r.output


def test_fast_large_motion_is_not_a_cut(tmp_path):
    """A box crossing ~1/3.5 of the frame per input frame: the histograms flag every pair
    (candidates), the motion check clears them all; with the check off (threshold above
    any score) nothing is flagged at all."""
    from fgcli.synth import load_scene, render_sequence

    sc = load_scene(os.path.join(ROOT, "tests", "scenes", "fastcross.toml"))
    render_sequence(sc, tmp_path / "fast", progress=False)
    cuts, _, _ = _run_cuts(tmp_path, tmp_path / "fast")
    assert cuts["cuts"] == []
    assert len(cuts["candidates"]) >= 2  # the histogram rule alone would have cut here
    assert all(c["explained"] >= 0.3 for c in cuts["candidates"])


def test_exposure_ramp_is_not_a_cut(tmp_path):
    frames = _first_frames("orbit", 6)
    gains = [1.6 ** i for i in range(6)]  # +0.7 stops per frame: histogram candidates
    _write_seq(tmp_path / "ramp", frames, gains)
    cuts, _, _ = _run_cuts(tmp_path, tmp_path / "ramp")
    assert cuts["cuts"] == [] and len(cuts["candidates"]) >= 3  # until the highlights clip


def test_spliced_shots_are_one_cut_and_nothing_is_blended(tmp_path):
    a = _first_frames("orbit", 4)
    b = _first_frames("throw", 4)
    _write_seq(tmp_path / "splice", a + b)
    cuts, out, log = _run_cuts(tmp_path, tmp_path / "splice")
    assert cuts["cuts"] == [7]  # output frame 7 lies between input 3 (orbit) and 4 (throw)
    assert "scene cuts" in log and "7" in log
    from fgcli.io.frames import read_frame

    got = read_frame(str(out / "s.0007.exr"), 7)
    # the nearest frame of one shot, exactly (half-float output of a half-float input)
    assert torch.equal(got.color, a[3].color.half().float()) or torch.equal(
        got.color, b[0].color.half().float())
    off, _, _ = _run_cuts(tmp_path, tmp_path / "splice", "--scene-cuts", "off",
                          "--overwrite")
    assert off["cuts"] == [] and off["candidates"] == []
