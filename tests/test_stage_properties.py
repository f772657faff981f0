"""Property tests over the hard cases of docs/design.md section 5, for every pipeline (and so
every registered stage) in every mode: finite output, shapes kept, zero motion returns the
input frame exactly, alpha -> 0 and -> 1 approach the endpoint frames."""
from __future__ import annotations

import math

import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fgcli import pipeline as pl
from fgcli.runner import make_ctx
from fgcli.frame import Frame

PIPES = [(n, m) for n in pl.available() for m in pl.load(n).modes]
SIZES = st.sampled_from([(1, 1), (1, 7), (5, 1), (3, 3), (7, 5), (13, 33)])
DEPTH_KIND = st.sampled_from(["normal", "zero", "inf", "mixed", "ndc"])
MV_KIND = st.sampled_from(["zero", "small", "huge", "offscreen", "converge", "nan"])
COLOR_KIND = st.sampled_from(["normal", "hdr", "tiny", "nonfinite"])


def make_frame(h, w, dk, mk, ck, seed, n=0):
    g = torch.Generator().manual_seed(seed)
    r = lambda *s: torch.rand(*s, generator=g)  # noqa: E731
    color = {"normal": r(3, h, w), "hdr": r(3, h, w) * 65504.0, "tiny": r(3, h, w) * 1e-7,
             "nonfinite": r(3, h, w)}[ck]
    if ck == "nonfinite":
        color = color.clone()
        color[0, 0, 0] = float("nan")
        color[1, -1, -1] = float("inf")
    depth = {"normal": 1 + 10 * r(1, h, w), "zero": torch.zeros(1, h, w),
             "inf": torch.full((1, h, w), math.inf), "ndc": r(1, h, w),
             "mixed": torch.where(r(1, h, w) > 0.5, torch.full((1, h, w), math.inf),
                                  1 + r(1, h, w))}[dk]
    yy, xx = torch.meshgrid(torch.arange(h) + 0.5, torch.arange(w) + 0.5, indexing="ij")
    mv = {"zero": torch.zeros(2, h, w), "small": (r(2, h, w) - 0.5) * 4,
          "huge": (r(2, h, w) - 0.5) * 1e7, "offscreen": torch.full((2, h, w), 3.0 * (h + w)),
          "converge": torch.stack([w / 2 - xx, h / 2 - yy]),
          "nan": torch.full((2, h, w), float("nan"))}[mk]
    return Frame(number=n, color=color, depth=depth, mv=mv, camera=make_camera(seed))


def make_camera(seed):
    """Every frame carries a camera (pipelines such as gffe-extrap require one): a 50 degree
    perspective camera near the origin looking down -Z, moved a little per seed."""
    import numpy as np

    from fgcli.frame import Camera

    g = np.random.default_rng(seed)
    w2c = np.eye(4)
    w2c[:3, 3] = -(g.random(3) - 0.5) * 0.2
    f, near, far = 1.0 / math.tan(math.radians(25.0)), 0.05, 1000.0
    proj = np.array([[f, 0, 0, 0], [0, f, 0, 0],
                     [0, 0, -(far + near) / (far - near), -2 * far * near / (far - near)],
                     [0, 0, -1, 0]])
    return Camera(w2c, proj)


def run(name, mode, f0, f1, alpha):
    p = pl.load(name)
    ctx = make_ctx(f0, f1, alpha, mode)
    ctx["prev_time"] = 0.0
    # random frames look like camera cuts (tested in test_scene_cut.py); here the stages
    return pl.run_stages(p.build(mode), ctx, detect_cuts=False)


@pytest.mark.parametrize("name,mode", PIPES)
@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(size=SIZES, dk=DEPTH_KIND, mk=MV_KIND, ck=COLOR_KIND, seed=st.integers(0, 10_000),
       alpha=st.sampled_from([0.0, 1e-6, 0.25, 0.5, 0.75, 1 - 1e-6, 1.0]))
def test_hard_cases_finite_and_shapes(name, mode, size, dk, mk, ck, seed, alpha):
    h, w = size
    f0 = make_frame(h, w, dk, mk, ck, seed, 0)
    f1 = make_frame(h, w, dk, mk, ck, seed + 1, 1)
    if mode == "extrap" and alpha == 0.0:
        alpha = 1e-6
    ctx = run(name, mode, f0, f1, alpha)
    assert ctx["color"].shape == (3, h, w)
    assert ctx["depth"].shape == (1, h, w)
    assert ctx["mv"].shape == (2, h, w)
    assert torch.isfinite(ctx["color"]).all()
    assert torch.isfinite(ctx["mv"]).all()
    assert not torch.isnan(ctx["depth"]).any()


@pytest.mark.parametrize("name,mode", PIPES)
@settings(max_examples=8, deadline=None)
@given(size=SIZES, dk=DEPTH_KIND, seed=st.integers(0, 10_000),
       alpha=st.sampled_from([0.1, 0.5, 0.9]))
def test_zero_motion_returns_the_input_exactly(name, mode, size, dk, seed, alpha):
    h, w = size
    f = make_frame(h, w, dk, "zero", "normal", seed)
    ctx = run(name, mode, f, f.replace(number=1), alpha)
    assert torch.equal(ctx["color"], f.color)


@pytest.mark.parametrize("name", [n for n, m in PIPES if m == "interp"])
@settings(max_examples=8, deadline=None)
@given(size=SIZES, mk=st.sampled_from(["small", "converge"]), seed=st.integers(0, 10_000))
def test_alpha_endpoints_approach_the_rendered_frames(name, size, mk, seed):
    h, w = size
    f0 = make_frame(h, w, "normal", mk, "normal", seed, 0)
    f1 = make_frame(h, w, "normal", mk, "normal", seed + 7, 1)
    near0 = run(name, "interp", f0, f1, 1e-4)["color"]
    near1 = run(name, "interp", f0, f1, 1 - 1e-4)["color"]
    at0 = run(name, "interp", f0, f1, 0.0)["color"]
    at1 = run(name, "interp", f0, f1, 1.0)["color"]
    # at the ends a generated frame is the rendered frame wherever it has a source
    if name != "repeat":
        assert (at0 - f0.color).abs().mean() <= (at1 - f0.color).abs().mean() + 1e-6
    assert torch.allclose(at1, f1.color, atol=1e-5)
    assert (near1 - f1.color).abs().mean() <= (near0 - f1.color).abs().mean() + 1e-6


@pytest.mark.parametrize("name", [n for n, m in PIPES if m == "extrap"])
def test_extrapolation_at_alpha_zero_plus_is_the_last_frame(name):
    f0 = make_frame(9, 11, "normal", "small", "normal", 1, 0)
    f1 = make_frame(9, 11, "normal", "small", "normal", 2, 1)
    out = run(name, "extrap", f0, f1, 1e-7)["color"]
    assert torch.allclose(out, f1.color, atol=1e-3)
