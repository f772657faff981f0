"""Data windows (real renders: a moving object's data window follows it across a bigger
display window): padding outside the window carries no data (alpha 0, depth +inf, vectors
invalid), outputs keep a data window that covers what they contain, and eval scores the
data windows by default. A sequence written with moving data windows and forward-only
vectors scores with mob-fgsr at least as well as the same pixels written full-frame."""
from __future__ import annotations

import math
import os

import numpy as np
import pytest
import torch
from click.testing import CliRunner

from fgcli.cli import cli
from fgcli.frame import Frame
from fgcli.io import exr
from fgcli.io.frames import read_frame, write_frame
from fgcli.io.reader import SequenceReader

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _object_only(sc, t, prev_t, name="ball"):
    """Frame t of `sc` with everything but object `name` removed (empty: black, no depth),
    as an element render over nothing; its tight data window."""
    from fgcli.synth import render

    ex = {}
    f = render(sc, t, prev_t, extras=ex, role="gt")
    keep = ex["object_id"] == sc.object_index(name)
    color = torch.where(keep[None], f.color, torch.zeros_like(f.color))
    depth = torch.where(keep[None], f.depth, torch.full_like(f.depth, math.inf))
    mv = f.mv  # empty pixels keep the renderer's vectors (background at infinity: camera)
    ys, xs = torch.nonzero(keep.any(1)).flatten(), torch.nonzero(keep.any(0)).flatten()
    h, w = keep.shape
    x0, y0 = max(int(xs[0]) - 2, 0), max(int(ys[0]) - 2, 0)
    x1, y1 = min(int(xs[-1]) + 3, w), min(int(ys[-1]) + 3, h)
    return Frame(number=0, color=color, depth=depth, mv=mv, camera=f.camera), (x0, y0, x1 - x0, y1 - y0)


@pytest.fixture(scope="module")
def element(tmp_path_factory):
    from fgcli.synth import load_scene

    tmp = tmp_path_factory.mktemp("dw")
    sc = load_scene(os.path.join(ROOT, "sample_data", "scenes", "throw.toml"), size=(128, 72),
                    spp=1)
    for kind in ("win", "full"):
        for sub in ("input", "gt"):
            os.makedirs(tmp / kind / sub)
    for n in range(0, 9):
        t = n / 2.0
        f, win = _object_only(sc, t, t - 1.0 if n % 2 == 0 else t - 0.5)
        fwd, _ = _object_only(sc, t, t + 1.0)
        sub = "input" if n % 2 == 0 else "gt"
        for kind in ("win", "full"):
            g = f.replace(number=n, data_window=win if kind == "win" else None)
            if sub == "input":  # forward vectors only, as Nuke-style renders have them
                g = g.replace(mv=None, mv_fwd=fwd.mv)
                write_frame(str(tmp / kind / sub / f"el.{n:04d}.exr"), g, layout="nuke")
            else:
                write_frame(str(tmp / kind / sub / f"el.{n:04d}.exr"), g)
    return tmp


def test_padding_is_read_as_no_data(element):
    r = SequenceReader(str(element / "win" / "input"))
    f = r.read(4)
    x, y, w, h = f.data_window
    assert w < f.width and h < f.height
    inside = torch.zeros(f.height, f.width, dtype=torch.bool)
    inside[y:y + h, x:x + w] = True
    assert torch.equal(f.alpha[0] > 0, inside)  # alpha 0 exactly on the padding
    assert torch.isinf(f.depth[0][~inside]).all()
    assert not f.mv_valid[0][~inside].any()  # no vectors there


def test_windowed_sequence_scores_at_least_as_well_as_full_frame(element, tmp_path):
    outs = {}
    for kind in ("win", "full"):
        r = CliRunner().invoke(cli, ["interpolate", str(element / kind / "input"),
                                     str(tmp_path / kind), "--pipeline", "mob-fgsr",
                                     "--no-progress"])
        assert r.exit_code == 0, r.output
        outs[kind] = tmp_path / kind
    gt = SequenceReader(str(element / "win" / "gt"))
    inp = SequenceReader(str(element / "win" / "input"))
    from fgcli.evaluate import region_box
    from fgcli.ops import psnr

    scores = {"win": [], "full": []}
    for n in gt.numbers:
        g = gt.read(n)
        box = region_box([g, inp.read(n - 1), inp.read(n + 1)])
        x, y, w, h = box
        for kind in scores:
            o = read_frame(str(outs[kind] / f"el.{n:04d}.exr"), n)
            scores[kind].append(float(psnr(o.color[:, y:y + h, x:x + w],
                                           g.color[:, y:y + h, x:x + w])))
        # the output's data window covers everything the frame contains
        hd = exr.read_header(str(outs["win"] / f"el.{n:04d}.exr")).parts[0]
        assert not hd.full_data_window
        o = read_frame(str(outs["win"] / f"el.{n:04d}.exr"), n)
        dm = torch.from_numpy(hd.data_mask())
        assert not torch.isfinite(o.depth[0][~dm]).any() and not o.color[:, ~dm].any()
    win, full = np.mean(scores["win"]), np.mean(scores["full"])
    print(f"data-window PSNR: windowed {win:.3f} dB, full-frame {full:.3f} dB")
    assert win >= full - 0.01, (win, full)


def test_eval_scores_the_data_windows_and_says_so(element, tmp_path):
    js = tmp_path / "e.json"
    r = CliRunner().invoke(cli, ["eval", str(element / "win"), "--pipeline", "mob-fgsr,blend",
                                 "--no-hdr-flip", "--no-progress", "--json", str(js)])
    assert r.exit_code == 0, r.output
    assert "# scored: the bounding box of the data windows" in r.output
    import json

    data = json.loads(js.read_text())
    r2 = CliRunner().invoke(cli, ["eval", str(element / "win"), "--pipeline", "mob-fgsr,blend",
                                  "--no-hdr-flip", "--no-progress", "--region", "display",
                                  "--json", str(tmp_path / "d.json")])
    assert r2.exit_code == 0, r2.output
    disp = json.loads((tmp_path / "d.json").read_text())
    assert data["region"]["scored_fraction"] < 0.5 and disp["region"]["scored_fraction"] == 1.0
    # the black padding inflates whole-frame scores; the data-window score does not hide it
    for p in ("mob-fgsr", "blend"):
        assert disp["pipelines"][p]["psnr"] > data["pipelines"][p]["psnr"] + 3.0
