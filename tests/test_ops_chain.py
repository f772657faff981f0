"""The full Mob-FGSR chains, run through the shipped pipeline file (pipelines/mob-fgsr.toml
and its stages): known answers and hard-case properties."""
from types import SimpleNamespace

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from fgcli.ops import (backward_warp, blend_interp, gap_fill, sample_nearest, splat_motion)
from fgcli.ops._testing import moving_square
from fgcli import pipeline as pl
from fgcli.runner import make_ctx


def _run(mode, f0, f1, alpha, sets):
    p = pl.load("mob-fgsr").with_overrides(sets) if sets else pl.load("mob-fgsr")
    # random test frames look like camera cuts; test the stages, not the cut policy
    ctx = pl.run_stages(p.build(mode), make_ctx(f0, f1, alpha, mode), detect_cuts=False)
    return SimpleNamespace(color=ctx["color"], depth=ctx["depth"], mv=ctx["mv"],
                           motion=ctx.get("motion"))


def interpolate(color0, depth0, mv0, color1, depth1, mv1, alpha, *, model="quadratic",
                dilate=1, check_depth0=True, fill="nearest", warp_mode="bilinear",
                use_target_depth=False):
    """mob-fgsr interpolation at alpha between frame 0 and frame 1, with option overrides."""
    f0 = SimpleNamespace(color=color0, depth=depth0, mv=mv0, camera=None)
    f1 = SimpleNamespace(color=color1, depth=depth1, mv=mv1, camera=None,
                         width=color1.shape[-1], height=color1.shape[-2])
    return _run("interp", f0, f1, alpha, [
        f"splat.motion={model}", f"dilate.radius={dilate}",
        f"splat.mv0_depth_check={check_depth0}", f"gap_fill.fill={fill}",
        f"warp.filter={warp_mode}", f"blend.target_depth={use_target_depth}"])


def extrapolate(color1, depth1, mv1, mv0, alpha, *, model="linear", dilate=1):
    """mob-fgsr extrapolation to 1 + alpha from frame 1 (frame 0's vectors: quadratic)."""
    f0 = SimpleNamespace(color=None, depth=None, mv=mv0, camera=None)
    f1 = SimpleNamespace(color=color1, depth=depth1, mv=mv1, camera=None,
                         width=color1.shape[-1], height=color1.shape[-2])
    return _run("extrap", f0, f1, alpha, [f"splat.motion={model}", f"dilate.radius={dilate}"])

INF = float("inf")
NAN = float("nan")


def frames(*ts, **kw):
    return [moving_square(t, **kw) for t in ts]


@pytest.mark.parametrize("alpha", [0.25, 0.5])
@pytest.mark.parametrize("model", ["linear", "quadratic"])
def test_translated_square_interpolates_exactly(alpha, model):
    (c0, d0, m0), (c1, d1, m1), (gt, dgt, _) = frames(0.0, 1.0, alpha)
    g = interpolate(c0, d0, m0, c1, d1, m1, alpha, model=model, dilate=0)
    assert torch.allclose(g.color, gt, atol=1e-3)
    assert torch.equal(g.depth, dgt)
    # the generated frame's vectors point to where each surface was in frame 0
    sq = dgt[0] == 2.0
    assert torch.allclose(g.mv[0][sq], torch.full((int(sq.sum()),), -4.0 * alpha))
    assert (g.mv[:, ~sq] == 0).all()


def test_dilated_chain_is_close_to_exact():
    (c0, d0, m0), (c1, d1, m1), (gt, _, _) = frames(0.0, 1.0, 0.5)
    g = interpolate(c0, d0, m0, c1, d1, m1, 0.5)  # dilation drags a 1-px bg halo along
    bad = (g.color - gt).abs().amax(0) > 1e-3
    assert bad.sum() <= 2 * (6 + 2) * 2 + 8  # at most the halo ring around the square


def test_near_object_wins_and_disocclusion_takes_background():
    (c0, d0, m0), (c1, d1, m1), (gt, _, _) = frames(0.0, 1.0, 0.5)
    r = gap_fill(splat_motion(d1, m1, m0, 0.5, depth0=d0), fallback_mv=m0)
    # the square (near) covers x = 18..23 at alpha = 0.5 although the background splats
    # there too
    assert (r.depth[0, 8:14, 18:24] == 2.0).all()
    c0s, v0 = backward_warp(c0, r.to0)
    c1s, v1 = backward_warp(c1, r.to1)
    d0s, _ = sample_nearest(d0, r.to0)
    d1s, _ = sample_nearest(d1, r.to1)
    # x = 16, 17: background at alpha, hidden in frame 0 -> taken from frame 1
    assert (d0s[0, 8:14, 16:18] == 2.0).all() and (d1s[0, 8:14, 16:18] == 10.0).all()
    # x = 24, 25: background at alpha, hidden in frame 1 -> taken from frame 0
    assert (d1s[0, 8:14, 24:26] == 2.0).all() and (d0s[0, 8:14, 24:26] == 10.0).all()
    out = blend_interp(c0s, c1s, d0s, d1s, v0, v1, alpha=0.5)
    assert torch.allclose(out[:, 8:14, 16:18], c1s[:, 8:14, 16:18])
    assert torch.allclose(out[:, 8:14, 24:26], c0s[:, 8:14, 24:26])
    assert torch.allclose(out, gt, atol=1e-3)


def test_extrapolation_of_square():
    (c0, d0, m0), (c1, d1, m1), (gt, _, _) = frames(0.0, 1.0, 1.5, x1=16)
    g = extrapolate(c1, d1, m1, m0, 0.5, dilate=0)
    sq = moving_square(1.5, x1=16)[1][0] == 2.0
    assert torch.allclose(g.color[:, sq], gt[:, sq], atol=1e-3)  # the square moved on
    static = ~sq
    static[:, 16:18] = False  # disocclusion behind the square: filled, not exact
    assert torch.allclose(g.color[:, static], gt[:, static], atol=1e-3)
    assert torch.isfinite(g.color).all()
    assert torch.allclose(g.mv[0][sq], torch.full((int(sq.sum()),), -2.0))


# ------------------------------------------------------------------ properties

SPECIAL_C = [0.0, 1e-30, 65504.0, INF, -INF, NAN]
SPECIAL_D = [0.0, 1e-30, 1e30, INF, NAN, -1.0]
SPECIAL_MV = [0.0, 1e9, -1e9, INF, NAN, 0.5]


@st.composite
def scene(draw, special=True):
    h = draw(st.integers(1, 7))
    w = draw(st.integers(1, 7))
    g = torch.Generator().manual_seed(draw(st.integers(0, 2 ** 31 - 1)))
    c0 = torch.rand(3, h, w, generator=g) * draw(st.sampled_from([1.0, 100.0]))
    c1 = torch.rand(3, h, w, generator=g)
    d0 = torch.rand(1, h, w, generator=g) * 10 + 0.1
    d1 = torch.rand(1, h, w, generator=g) * 10 + 0.1
    kind = draw(st.sampled_from(["zero", "small", "large", "collapse"]))
    if kind == "zero":
        m0 = torch.zeros(2, h, w)
        m1 = torch.zeros(2, h, w)
    elif kind == "collapse":  # every pixel of frame 1 came from one pixel of frame 0
        yy, xx = torch.meshgrid(torch.arange(h, dtype=torch.float32),
                                torch.arange(w, dtype=torch.float32), indexing="ij")
        m1 = torch.stack([0.0 - xx, 0.0 - yy])
        m0 = m1.clone()
    else:
        s = 2.0 if kind == "small" else 50.0
        m0 = (torch.rand(2, h, w, generator=g) - 0.5) * s
        m1 = (torch.rand(2, h, w, generator=g) - 0.5) * s
    if special:
        for t, vals in ((c0, SPECIAL_C), (c1, SPECIAL_C), (d0, SPECIAL_D), (d1, SPECIAL_D),
                        (m0, SPECIAL_MV), (m1, SPECIAL_MV)):
            for _ in range(draw(st.integers(0, 2))):
                t[draw(st.integers(0, t.shape[0] - 1)), draw(st.integers(0, h - 1)),
                  draw(st.integers(0, w - 1))] = draw(st.sampled_from(vals))
    return c0, d0, m0, c1, d1, m1


@settings(max_examples=25, deadline=None)
@given(scene(), st.sampled_from([0.0, 1e-6, 0.3, 0.5, 0.999999, 1.0]),
       st.sampled_from(["linear", "quadratic"]), st.integers(0, 1))
def test_interp_chain_always_finite(sc, alpha, model, dilate):
    c0, d0, m0, c1, d1, m1 = sc
    saved = [t.clone() for t in sc]
    g = interpolate(c0, d0, m0, c1, d1, m1, alpha, model=model, dilate=dilate,
                    use_target_depth=bool(dilate))
    h, w = c0.shape[1:]
    assert g.color.shape == (3, h, w) and torch.isfinite(g.color).all()
    assert g.mv.shape == (2, h, w) and torch.isfinite(g.mv).all()
    assert g.depth.shape == (1, h, w) and not torch.isnan(g.depth).any()
    for a, b in zip(sc, saved):
        assert torch.equal(a.nan_to_num(3.0), b.nan_to_num(3.0))


@settings(max_examples=25, deadline=None)
@given(scene(), st.sampled_from([0.0, 0.5, 1.0, 3.0]), st.sampled_from(["linear", "quadratic"]))
def test_extrap_chain_always_finite(sc, alpha, model):
    c0, d0, m0, c1, d1, m1 = sc
    g = extrapolate(c1, d1, m1, m0, alpha, model=model)
    assert torch.isfinite(g.color).all() and torch.isfinite(g.mv).all()
    assert g.color.shape == c1.shape and not torch.isnan(g.depth).any()


@settings(max_examples=25, deadline=None)
@given(scene(special=False), st.sampled_from(["linear", "quadratic"]), st.integers(0, 1))
def test_interp_endpoints_are_the_rendered_frames(sc, model, dilate):
    c0, d0, m0, c1, d1, m1 = sc
    g0 = interpolate(c0, d0, m0, c1, d1, m1, 0.0, model=model, dilate=dilate)
    assert torch.equal(g0.color, c0)
    g1 = interpolate(c0, d0, m0, c1, d1, m1, 1.0, model=model, dilate=dilate)
    assert torch.equal(g1.color, c1)
    assert (g1.mv == g1.motion.to0).all()
    # close to the ends the result approaches the rendered frames where vectors are
    # trivial (static pixels)
    ge = interpolate(c0, d0, m0, c1, d1, m1, 1e-6, model=model, dilate=dilate)
    assert torch.isfinite(ge.color).all()


@settings(max_examples=25, deadline=None)
@given(scene(special=False), st.sampled_from([0.0, 0.25, 0.5, 0.8, 1.0]),
       st.sampled_from(["linear", "quadratic"]))
def test_zero_motion_returns_the_frame(sc, alpha, model):
    c0, d0, _, _, _, _ = sc
    z = torch.zeros(2, *c0.shape[1:])
    g = interpolate(c0, d0, z, c0, d0, z, alpha, model=model)
    assert torch.equal(g.color, c0)
    assert (g.mv == 0).all()
    e = extrapolate(c0, d0, z, z, alpha, model=model)
    assert torch.equal(e.color, c0)


@settings(max_examples=25, deadline=None)
@given(scene(special=False), st.sampled_from(["linear", "quadratic"]))
def test_interp_approaches_endpoints(sc, model):
    c0, _, m0, c1, _, m1 = sc
    h, w = c0.shape[1:]
    flat = torch.full((1, h, w), 3.0)  # one depth: no disocclusion decisions
    # the difference is O(alpha * |mv| * colour gradient): |mv| <= 25 px here
    tol = 1e-3 + 1e-4 * float(max(c0.abs().max(), c1.abs().max()))
    g = interpolate(c0, flat, m0, c1, flat, m1, 1e-6, model=model)
    assert torch.allclose(g.color, c0, atol=tol, rtol=0)
    g = interpolate(c0, flat, m0, c1, flat, m1, 1.0 - 1e-6, model=model)
    assert torch.allclose(g.color, c1, atol=tol, rtol=0)


def test_batched_chain_pieces():
    (c0, d0, m0), (c1, d1, m1) = frames(0.0, 1.0)
    B = lambda t: torch.stack([t, t])  # noqa: E731
    r = gap_fill(splat_motion(B(d1), B(m1), B(m0), 0.5, depth0=B(d0)), fallback_mv=B(m0))
    c0s, v0 = backward_warp(B(c0), r.to0)
    c1s, v1 = backward_warp(B(c1), r.to1)
    d0s, _ = sample_nearest(B(d0), r.to0)
    d1s, _ = sample_nearest(B(d1), r.to1)
    out = blend_interp(c0s, c1s, d0s, d1s, v0, v1, alpha=0.5)
    single = interpolate(c0, d0, m0, c1, d1, m1, 0.5, dilate=0)
    assert out.shape == (2, 3, *c0.shape[1:])
    assert torch.equal(out[0], single.color) and torch.equal(out[1], single.color)


def test_bench_smoke(capsys):
    import importlib.util
    import os

    path = os.path.join(os.path.dirname(os.path.dirname(__file__)), "benchmarks", "ops.py")
    spec = importlib.util.spec_from_file_location("bench_ops", path)
    _bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(_bench)
    _bench.main(["--size", "40x24", "--runs", "1", "--no-tune"])
    out = capsys.readouterr().out
    assert "INTERP chain" in out and "EXTRAP chain" in out
