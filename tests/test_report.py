"""`fgen eval --report` (issue 61, item 5): one self-contained page, the figures as PNG, a
Markdown summary, earlier outputs cleared; the page opened in a real headless browser."""
from __future__ import annotations

import os
import re
import shutil
import subprocess

import numpy as np
import pytest
import torch

from fgcli.report import merge_repeats, write_report

CHROMIUM = shutil.which("chromium") or ("/usr/bin/chromium"
                                        if os.path.exists("/usr/bin/chromium") else None)


def _result(names, frames=(1, 3, 5)):
    pipes = {}
    for i, n in enumerate(names):
        pipes[n] = {"psnr": 30.0 + i, "ssim": 0.9, "flip": 0.05 - 0.01 * i, "flip_hdr": float("nan"),
                    "psnr_disoccluded": 25.0, "psnr_moving": 28.0, "ms_per_frame": 5.0 + i,
                    "stages": {"facts": 1.0, f"s{i}": 4.0 + i},
                    "per_frame": [{"frame": f, "psnr": 30.0 + i + 0.1 * f} for f in frames]}
    return {"mode": "interp", "frames": len(frames), "pipelines": pipes, "sequence": "toy",
            "display": "sRGB OETF of clip(linear, 0, 1)", "backend": "torch", "repeats": 1}


def _compare(names, h=30, w=40):
    g = torch.Generator().manual_seed(0)
    gt = torch.rand(3, h, w, generator=g)
    outs = {n: (gt + 0.05 * (i + 1) * torch.rand(3, h, w, generator=g)).clamp(0, 1)
            for i, n in enumerate(names)}
    return {"frame": 3, "gt": gt, "outs": outs, "psnr": {n: 30.0 for n in names}}


def test_report_files_self_contained_and_cleared(tmp_path):
    names = ["mob-fgsr", "blend", "repeat"]
    files = write_report(_result(names), {}, str(tmp_path), compare=_compare(names))
    rel = {os.path.relpath(f, tmp_path) for f in files}
    assert {"index.html", "summary.md", "quality_vs_time.png", "per_frame_psnr.png",
            "stage_times.png", "crops.png", "colorbar.png", "crops/gt.png", "crops/gt_x4.png",
            "crops/blend_error_x4.png"} <= rel
    for f in files:
        if f.endswith(".png"):
            assert open(f, "rb").read(4) == b"\x89PNG"
    # 1:1 crops have the crop's pixels; zoomed x4
    import matplotlib.image as mpimg

    a, b = mpimg.imread(tmp_path / "crops/blend.png"), mpimg.imread(tmp_path / "crops/blend_x4.png")
    assert a.shape[:2] == (30, 40) and b.shape[:2] == (120, 160)
    page = (tmp_path / "index.html").read_text()
    srcs = re.findall(r'src="([^"]*)"', page)
    assert srcs and all(s.startswith("data:image/png;base64,") for s in srcs)
    assert "http://" not in page and "https://" not in page  # no network
    assert "<table>" in page and "mob-fgsr" in page
    md = (tmp_path / "summary.md").read_text()
    assert "| mob-fgsr |" in md and "![Quality vs time](quality_vs_time.png)" in md
    # an earlier report's own files go; a user's file stays
    (tmp_path / "notes.txt").write_text("mine")
    (tmp_path / "worst_old.png").write_bytes(b"x")
    write_report(_result(["blend"]), {}, str(tmp_path), compare=_compare(["blend"]))
    assert not (tmp_path / "crops/mob-fgsr.png").exists()
    assert (tmp_path / "crops/blend.png").exists() and (tmp_path / "notes.txt").exists()


def test_repeats_give_median_and_spread():
    runs = []
    for ms in (10.0, 30.0, 12.0):
        r = _result(["a"])
        r["pipelines"]["a"]["ms_per_frame"] = ms
        runs.append(r)
    m = merge_repeats(runs)
    assert m["repeats"] == 3
    assert m["pipelines"]["a"]["ms_per_frame"] == 12.0
    assert m["pipelines"]["a"]["ms_per_frame_spread"] == [10.0, 30.0]


@pytest.mark.skipif(CHROMIUM is None, reason="no headless browser: /usr/bin/chromium is "
                    "missing (Debian: apt-get install chromium)")
def test_report_page_in_headless_chromium(tmp_path):
    names = ["mob-fgsr", "mv-warp", "blend", "repeat"]
    rep = tmp_path / "rep"
    write_report(_result(names), {}, str(rep), compare=_compare(names))
    url = "file://" + str(rep / "index.html")
    base = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu",
            "--disable-background-networking", "--disable-component-update",
            "--no-first-run", "--hide-scrollbars", f"--user-data-dir={tmp_path / 'prof'}"]
    dom = subprocess.run(base + ["--virtual-time-budget=5000", "--dump-dom", url],
                         capture_output=True, text=True, timeout=120)
    m = re.search(r'data-images="(\d+)" data-images-shown="(\d+)"', dom.stdout)
    assert m, dom.stdout[:500] + dom.stderr[-2000:]
    total, shown = int(m.group(1)), int(m.group(2))
    assert total >= 3 + 1 + 3 * len(names) + 2 + 1 and shown == total  # every figure shown
    shot = tmp_path / "page.png"
    subprocess.run(base + ["--window-size=1280,2600", f"--screenshot={shot}", url],
                   capture_output=True, timeout=120)
    import matplotlib.image as mpimg

    img = mpimg.imread(shot)[..., :3]
    assert img.shape[0] >= 2000 and img.shape[1] == 1280
    ink = (img < 0.9).any(axis=2)  # non-white pixels
    rows = ink.any(axis=1)
    # laid out: content from the title down the page, not one blob or an empty page
    assert rows[:200].any() and rows[200:1200].mean() > 0.3 and rows[1200:].any()
    assert 0.02 < ink.mean() < 0.8
