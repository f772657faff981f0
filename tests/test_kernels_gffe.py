"""gffe's camera geometry kernels (fgcli.kernels.geom via fgcli.kernels.ops.unproject /
project) against the torch functions of fgcli.ops.gffe on random cameras and the hard
cases, the gffe ops with the kernels (``geom``) against the reference, and the whole
gffe-extrap pipeline with --backend numba against torch.

The geometry uses only float32 multiplications, additions and divisions (correctly rounded
on every CPU) and torch's own sqrt for the sky: its contract is exact, compared bit for
bit. The fused ops that sample bilinearly or fill from pyramids compare under their
contracts (fgcli.kernels.contract), on every CPU."""
from __future__ import annotations

import math
import os

import numpy as np
import pytest
import torch

pytest.importorskip("numba")

from fgcli.kernels import ops as K  # noqa: E402
from fgcli.ops import gffe as G  # noqa: E402
from fgcli.kernels.contract import CONTRACTS, PIPELINE, check  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
INF, NAN = float("inf"), float("nan")


def bits_equal(name, a, b):
    """Same shape, dtype and bits (floats compared as int32: -0.0 != 0.0, NaN payloads
    equal). The outputs are finite by contract, so NaN bits never come into it."""
    assert a.shape == b.shape and a.dtype == b.dtype, (name, a.shape, b.shape, a.dtype, b.dtype)
    if a.dtype == torch.float32:
        eq = a.contiguous().view(torch.int32) == b.contiguous().view(torch.int32)
    else:
        eq = a == b
    assert bool(eq.all()), f"{name}: {int((~eq).sum())} of {eq.numel()} differ"


def same_tree(name, a, b):
    if isinstance(a, torch.Tensor):
        bits_equal(name, a, b)
    elif isinstance(a, dict):
        assert a.keys() == b.keys(), name
        for k in a:
            same_tree(f"{name}.{k}", a[k], b[k])
    elif isinstance(a, (tuple, list)):
        assert len(a) == len(b), name
        for i, (x, y) in enumerate(zip(a, b)):
            same_tree(f"{name}[{i}]", x, y)
    else:
        assert a == b, name


# ----------------------------------------------------------------------------- cameras

def perspective(fov, aspect, near, far, skew=0.0, shift=(0.0, 0.0)):
    f = 1.0 / math.tan(math.radians(fov / 2))
    return np.array([[f / aspect, skew, shift[0], 0], [0, f, shift[1], 0],
                     [0, 0, -(far + near) / (far - near), -2 * far * near / (far - near)],
                     [0, 0, -1, 0]])


def orthographic(half_w, half_h, near, far):
    return np.array([[1 / half_w, 0, 0, 0], [0, 1 / half_h, 0, 0],
                     [0, 0, -2 / (far - near), -(far + near) / (far - near)], [0, 0, 0, 1.0]])


def random_camera(rng, aspect):
    pos = rng.normal(size=3) * 5
    view = G.look_at(pos, rng.normal(size=3), rng.normal(size=3))
    kind = rng.integers(0, 3)
    if kind == 0:
        p = perspective(rng.uniform(10, 120), aspect, rng.uniform(1e-3, 1.0),
                        rng.uniform(10, 1e5))
    elif kind == 1:  # off-axis, skewed
        p = perspective(rng.uniform(20, 90), aspect, 0.05, 1000.0, rng.uniform(-0.2, 0.2),
                        tuple(rng.uniform(-0.5, 0.5, 2)))
    else:
        p = orthographic(rng.uniform(1, 20), rng.uniform(1, 20), 0.1, 500.0)
    return view, p


def hard_depth(h, w, rng, scale=50.0):
    g = torch.Generator().manual_seed(int(rng.integers(1 << 30)))
    d = torch.rand(1, h, w, generator=g) * scale + 1e-3
    flat = d.view(-1)
    n = flat.numel()
    for value in (INF, 0.0, -3.0, NAN, -INF, 1e-30, 3e38, 1e-45):
        k = max(1, n // 12)
        flat[torch.randint(0, n, (k,), generator=g)] = value
    if h > 2:
        d[0, : h // 3] = INF  # sky rows
    return d


SIZES = [(1, 1), (1, 17), (13, 1), (7, 13), (37, 53), (64, 96)]


@pytest.mark.parametrize("h,w", SIZES)
def test_unproject_is_bit_identical(h, w):
    rng = np.random.default_rng(h * 1000 + w)
    for trial in range(4):
        cam = random_camera(rng, w / h)
        d = hard_depth(h, w, rng)
        bits_equal(f"default grid {trial}", K.unproject(d, cam), G.unproject(d, cam))
        # sample coordinates: random, huge, off-screen, some non-finite; another size
        g = torch.Generator().manual_seed(trial)
        px = (torch.rand(h, w, generator=g) * 3 - 1) * w
        py = (torch.rand(h, w, generator=g) * 3 - 1) * h
        px.view(-1)[:: 7] = 1e8
        py.view(-1)[3:: 11] = -1e9
        if h * w > 20:
            px.view(-1)[5] = NAN
            py.view(-1)[9] = INF
        size = (h + 3, max(1, w - 2))
        bits_equal(f"samples {trial}", K.unproject(d, cam, px, py, size),
                   G.unproject(d, cam, px, py, size))
        # separable (expanded) centres, as the background layers pass them
        cx, cy = G._centres(h, w, 2.0, "cpu")
        bits_equal(f"centres {trial}", K.unproject(d, cam, cx, cy, (2 * h, 2 * w)),
                   G.unproject(d, cam, cx, cy, (2 * h, 2 * w)))


def test_ray_tables_hold_for_separable_cameras_only():
    """ray_tables (rays per column and per row instead of per pixel) holds for a
    perspective camera on the pixel grid, and not for a skewed one, a column whose ray
    has x = 0 (odd width: the sign of a zero term would count), or samples that are not a
    grid; unproject and reproject match the reference either way (sky rows included)."""
    from fgcli.kernels.geom import ray_tables

    rng = np.random.default_rng(11)
    cases = [("perspective", perspective(60, 1.5, 0.1, 100.0), 24, 36, True),
             ("orthographic", orthographic(4, 3, 0.1, 50.0), 24, 36, True),
             ("off-axis", perspective(50, 1.5, 0.1, 100.0, 0.0, (0.2, -0.1)), 24, 36, True),
             ("skewed", perspective(60, 1.5, 0.1, 100.0, 0.1), 24, 36, False),
             ("odd width", perspective(60, 1.5, 0.1, 100.0), 24, 35, False)]
    for name, proj, h, w, holds in cases:
        cam = (G.look_at(rng.normal(size=3), rng.normal(size=3), rng.normal(size=3)), proj)
        cam_b = random_camera(rng, w / h)
        gx, gy = K._grid_half(h, w)
        kx, ky, A, _ = K._unproject_coefs(cam, (h, w))
        assert ray_tables(gx, gy, kx, ky, A)[0] == holds, name
        d = hard_depth(h, w, rng)
        bits_equal(f"unproject {name}", K.unproject(d, cam), G.unproject(d, cam))
        same_tree(f"reproject {name}", K.reproject(d, cam, cam_b, (h, w)),
                  G.project(G.unproject(d, cam), cam_b, (h, w)))
    px = torch.rand(4, 6, generator=torch.Generator().manual_seed(1)) * 6  # (not a grid)
    assert not ray_tables(px.numpy(), px.numpy()[:, :1].copy(), *K._unproject_coefs(
        (np.eye(4), perspective(60, 1.5, 0.1, 100.0)), (4, 6))[:3])[0]


def test_sky_passes_skip_spans_without_sky():
    """The sky passes work in spans of SKY_SPAN pixels and skip those with no sky: wide
    rows whose sky lies in a few runs (across span boundaries, at the row's end, a lone
    pixel), the rest surfaces; unproject and reproject against the reference."""
    from fgcli.kernels.geom import SKY_SPAN

    h, w = 6, 3 * SKY_SPAN + 17
    rng = np.random.default_rng(5)
    d = torch.rand(1, h, w, generator=torch.Generator().manual_seed(5)) * 20 + 1
    d[0, 1, SKY_SPAN - 3:SKY_SPAN + 5] = INF  # across a span boundary
    d[0, 2, w - 4:] = INF  # the last, partial span
    d[0, 3, 2 * SKY_SPAN + 7] = INF  # one pixel
    d[0, 4, :] = INF  # a whole sky row
    for trial in range(3):
        cam_a, cam_b = random_camera(rng, w / h), random_camera(rng, w / h)
        bits_equal(f"unproject {trial}", K.unproject(d, cam_a), G.unproject(d, cam_a))
        same_tree(f"reproject {trial}", K.reproject(d, cam_a, cam_b, (h, w)),
                  G.project(G.unproject(d, cam_a), cam_b, (h, w)))


@pytest.mark.parametrize("h,w", SIZES)
def test_reproject_is_project_of_unproject(h, w):
    """The fused reproject (positions kept in row buffers) gives project(unproject(...))
    bit for bit: hard depths (sky rows and pixels, NaN, negative), random cameras on
    both sides, the default grid, random samples and the layers' separable centres."""
    rng = np.random.default_rng(h * 31 + w)
    for trial in range(4):
        cam_a, cam_b = random_camera(rng, w / h), random_camera(rng, w / h)
        d = hard_depth(h, w, rng)
        size = (h, w)
        same_tree(f"default grid {trial}", K.reproject(d, cam_a, cam_b, size),
                  G.project(G.unproject(d, cam_a), cam_b, size))
        g = torch.Generator().manual_seed(trial)
        px = (torch.rand(h, w, generator=g) * 3 - 1) * w
        py = (torch.rand(h, w, generator=g) * 3 - 1) * h
        big = (h + 3, max(1, w - 2))
        same_tree(f"samples {trial}", K.reproject(d, cam_a, cam_b, big, px, py),
                  G.project(G.unproject(d, cam_a, px, py, big), cam_b, big))
        cx, cy = G._centres(h, w, 2.0, "cpu")
        full = (2 * h, 2 * w)
        same_tree(f"centres {trial}", K.reproject(d, cam_a, cam_b, full, cx, cy),
                  G.project(G.unproject(d, cam_a, cx, cy, full), cam_b, full))
        # a layer's fragments: the valid mask inside the kernel (sky, NaN, negative depths
        # in valid and invalid cells; every row, or the rows marked)
        valid = torch.rand(1, h, w, generator=g) < 0.6
        valid[0, 0] = True  # (a sky row)
        layer = {"depth": d, "valid": valid, "color": torch.zeros(3, h, w)}
        same_tree(f"layer fragments {trial}",
                  K._layer_fragments(layer, cam_a, cam_b, full, 2.0),
                  G._layer_fragments(layer, cam_a, cam_b, full, 2.0))
        rows = (torch.rand(h, generator=g) < 0.5).to(torch.uint8).numpy()
        rows[0] = 1
        k = K.reproject(d, cam_a, cam_b, size, rows=rows, valid=valid)
        r = G.project(G.unproject(torch.where(valid, d, 0.0), cam_a), cam_b, size)
        r = r[:3] + (r[3] & valid[0],)
        sel = torch.from_numpy(rows.astype(bool))
        same_tree(f"masked rows {trial}", [t[sel] for t in k], [t[sel] for t in r])
        # runs of 3 pixels (fill_holes': of 64): rows with none, some and all of their runs
        # marked; the marked runs' pixels as the reference's, sky among them
        run = 3
        nr = -(-w // run)
        runs = (torch.rand(h, nr, generator=g) < 0.4).to(torch.uint8).numpy()
        runs[0] = 1
        runs[h // 2] = 0
        sel = torch.from_numpy(np.repeat(runs.astype(bool), run, axis=1)[:, :w])
        vrun = np.ones((h, w), dtype=np.uint8)  # (a hole in each marked run)
        vrun[:, ::run] = (~sel.numpy()[:, ::run]).astype(np.uint8)
        k = K.reproject(d, cam_a, cam_b, size, rows=runs.max(axis=1), run=run, vrun=vrun)
        r = G.project(G.unproject(d, cam_a), cam_b, size)
        same_tree(f"marked runs {trial}", [t[sel] for t in k], [t[sel] for t in r])


@pytest.mark.parametrize("h,w", SIZES)
def test_project_is_bit_identical(h, w):
    rng = np.random.default_rng(h * 7 + w)
    for trial in range(4):
        cam_a, cam_b = random_camera(rng, w / h), random_camera(rng, w / h)
        d = hard_depth(h, w, rng)
        X = G.unproject(d, cam_a)  # surfaces, sky directions, zeros; many behind cam_b
        same_tree(f"unprojected {trial}", K.project(X, cam_b, (h, w)), G.project(X, cam_b, (h, w)))
        # arbitrary homogeneous positions: huge, negative w, non-finite, all zero
        g = torch.Generator().manual_seed(100 + trial)
        Y = torch.randn(4, h, w, generator=g) * 10
        Y[3] = torch.where(torch.rand(h, w, generator=g) < 0.3, torch.zeros(h, w), Y[3])
        flat = Y.view(4, -1)
        n = flat.shape[1]
        for value in (0.0, -0.0, 1e30, -1e30, INF, -INF, NAN, 1e-40):
            flat[torch.randint(0, 4, (max(1, n // 10),), generator=g),
                 torch.randint(0, n, (max(1, n // 10),), generator=g)] = value
        flat[:, 0] = 0.0
        same_tree(f"random {trial}", K.project(Y, cam_b, (h + 1, w + 5)),
                  G.project(Y, cam_b, (h + 1, w + 5)))


def test_project_takes_any_trailing_shape():
    rng = np.random.default_rng(5)
    cam = random_camera(rng, 1.5)
    X = G.unproject(hard_depth(6, 10, rng), random_camera(rng, 1.5))
    for Y in (X.reshape(4, 60), X.reshape(4, 3, 2, 10), X[:, :, ::2]):
        same_tree(f"shape {tuple(Y.shape)}", K.project(Y, cam, (6, 10)),
                  G.project(Y, cam, (6, 10)))


def test_other_inputs_run_the_reference():
    rng = np.random.default_rng(6)
    cam = random_camera(rng, 1.0)
    d = hard_depth(5, 5, rng)
    # float64 depth or samples, a batch, a non-CPU (meta) tensor: the torch function
    bits_equal("float64", K.unproject(d.double(), cam), G.unproject(d.double(), cam))
    px = G.aux(5, 5, "cpu")["xh"].expand(5, 5).double()
    py = G.aux(5, 5, "cpu")["yh"].expand(5, 5).double()
    bits_equal("float64 samples", K.unproject(d, cam, px, py), G.unproject(d, cam, px, py))
    m = K.unproject(d.to("meta"), cam)
    assert m.device.type == "meta" and m.shape == (4, 5, 5)
    out = K.project(G.unproject(d, cam).to("meta"), cam, (5, 5))
    assert all(t.device.type == "meta" for t in out)
    with pytest.raises(ValueError, match="non-finite"):
        K.unproject(d, (np.full((4, 4), np.nan), np.eye(4)))


# ----------------------------------------------------------------------------- ops

def _frames(h=24, w=40, seed=0):
    g = torch.Generator().manual_seed(seed)
    view = G.look_at([0.0, 0.5, 3.0], [0.05, -0.1, -1.0], [0, 1, 0])
    cam1 = (view, perspective(60, w / h, 0.05, 500.0))
    cam0 = (G.look_at([-0.15, 0.45, 3.1], [0.0, -0.1, -1.0], [0, 1, 0]), cam1[1])
    cam_x = G.extrapolate_camera(cam0, cam1, 0.5, "rigid")
    d1 = torch.rand(1, h, w, generator=g) * 4 + 2
    d1[0, :h // 6] = INF
    d1[0, h // 2, 3:6] = 0.0
    d1[0, h // 2 + 1, 3:6] = NAN
    d0 = d1.roll(1, -1) * 1.01
    mv1 = torch.randn(2, h, w, generator=g) * 2
    c1 = torch.rand(3, h, w, generator=g)
    return dict(cam0=cam0, cam1=cam1, cam_x=cam_x, d0=d0, d1=d1, mv1=mv1, c1=c1, h=h, w=w)


def test_gffe_ops_with_the_kernels_are_bit_identical():
    f = _frames()
    h, w = f["h"], f["w"]
    cases = []
    th = lambda **k: G.track_history(f["d1"], f["mv1"], f["cam1"], **k)  # noqa: E731
    cases.append(("history first frame", lambda geom: th(geom=geom)))
    cases.append(("history", lambda geom: th(cam0=f["cam0"], depth0=f["d0"], geom=geom)))
    cases.append(("history nearest", lambda geom: th(cam0=f["cam0"], depth0=f["d0"],
                                                     lookup="nearest", geom=geom)))
    traj, dyn = G.track_history(f["d1"], f["mv1"], f["cam1"], f["cam0"], f["d0"])
    cases.append(("history prev", lambda geom: th(cam0=f["cam0"], prev=traj, k=3, geom=geom)))
    cases.append(("dilate", lambda geom: G.dilate_trajectory(traj, f["d1"], f["cam1"], dyn,
                                                             geom=geom)))
    pos = G.estimate_positions(traj, 0.5)
    cases.append(("warp", lambda geom: G.warp_positions(f["c1"], pos, f["cam_x"], geom=geom)))
    layers = G.collect_background(f["c1"], f["d0"], ~dyn, f["cam0"], layer1_scale=1)
    for sc in (1, 2):
        cases.append((f"collect {sc}", lambda geom, sc=sc: G.collect_background(
            f["c1"], f["d1"], ~dyn, f["cam1"], layers, f["cam0"], 0.02, True, sc, geom=geom)))
    holes = torch.rand(1, h, w, generator=torch.Generator().manual_seed(3)) < 0.3
    for filt in ("nearest", "bilinear"):
        cases.append((f"project bg {filt}", lambda geom, filt=filt: G.project_background(
            layers, f["cam1"], f["cam_x"], holes, filt, geom=geom)))
    b = 3
    border = {"origin": (-b, -b), "color": torch.rand(3, h + 2 * b, w + 2 * b),
              "depth": torch.nn.functional.pad(f["d1"], (b, b, b, b), value=5.0)}
    cases.append(("border", lambda geom: G.project_border(border, f["cam1"], f["cam_x"], holes,
                                                          geom=geom)))
    dfill = torch.where(holes, torch.full_like(f["d1"], 4.0), f["d1"])
    for off in ("clamp", "skip"):
        for bd in (None, border):
            cases.append((f"reproject {off} {bd is not None}",
                          lambda geom, off=off, bd=bd: G.reproject_fill(
                              f["c1"], ~holes, dfill, f["c1"], f["d1"], f["cam1"], f["cam_x"],
                              offscreen=off, border=bd, geom=geom)))
    for name, call in cases:
        same_tree(name, call(K.GEOM), call(None))


def test_dispatch_gives_the_kernel_versions():
    from fgcli.kernels import KERNEL_OPS, op

    names = [n for n, m in KERNEL_OPS.items() if m == "fgcli.ops.gffe"]
    assert {"track_history", "warp_positions", "project_background", "reproject_fill"} <= set(
        names)
    for n in names:
        assert op(n, {"backend": "torch"}) is getattr(G, n)
        assert op(n, {"backend": "numba"}) is getattr(K, n)
    f = _frames(8, 12, 1)
    a = op("track_history", {"backend": "numba"})(f["d1"], f["mv1"], f["cam1"], f["cam0"],
                                                  f["d0"])
    same_tree("track_history", a, G.track_history(f["d1"], f["mv1"], f["cam1"], f["cam0"],
                                                  f["d0"]))


# ----------------------------------------------------------------------------- pipeline

@pytest.fixture(scope="module")
def orbit_frames():
    """Four frames of the bundled orbit scene (orbiting camera, sky, shadows) at 64x36,
    the last two with a synthetic 4-pixel overscan border."""
    from fgcli.synth import load_scene, render

    scene = load_scene(os.path.join(ROOT, "sample_data", "scenes", "orbit.toml"), size=(64, 36))
    frames = [render(scene, 2.0 + i, 1.0 + i, spp=1) for i in range(4)]
    g = torch.Generator().manual_seed(0)
    out = []
    for i, f in enumerate(frames):
        if i >= 2:
            b = 4
            d = torch.nn.functional.pad(f.depth, (b, b, b, b), value=INF)
            d[:, -b:] = torch.rand(1, b, d.shape[-1], generator=g) * 5 + 1
            f = f.replace(overscan={"origin": (-b, -b), "depth": d,
                                    "color": torch.rand(3, *d.shape[-2:], generator=g)})
        out.append(f)
    return out


def _run(name, frames, backend, alpha):
    from fgcli import pipeline as pl
    from fgcli.pipeline import frame_facts, run_stages
    from fgcli.runner import RunState, make_ctx

    stages = pl.load(name).build("extrap")
    state = RunState()
    outs = []
    with torch.inference_mode():
        for f0, f1 in zip([None] + frames[:-1], frames):
            ctx = make_ctx(f0, f1, alpha, "extrap")
            ctx.update(prev_time=0.0, state=state, backend=backend)
            out = run_stages(stages, ctx, None, facts=frame_facts(ctx))
            outs.append({k: out[k] for k in ("color", "depth", "mv")})
    return outs


@pytest.mark.parametrize("name", [
    "gffe-extrap",
    # the paper's variants: nearest lookup, quarter-size layer 1, no dilation, nearest
    # background filter, linear camera model, push-pull only
    "gffe-extrap:history.lookup=nearest,background.layer1_scale=2,position.dilate=full,"
    "bg_project.filter=nearest,camera.model=linear,hole_fill.offscreen=skip",
])
def test_gffe_extrap_numba_equals_torch(orbit_frames, name, monkeypatch):
    seen = []

    def unproject(depth, *a, **k):
        seen.append(tuple(depth.shape[-2:]))
        return K.unproject(depth, *a, **k)

    monkeypatch.setattr(K, "GEOM", G.Geometry(unproject, K.project))
    monkeypatch.setattr(K, "_EMPTY_LAYERS", {})
    for alpha in (0.5, 1.0):
        a = _run(name, orbit_frames, "numba", alpha)
        b = _run(name, orbit_frames, "torch", alpha)
        for i, (x, y) in enumerate(zip(a, b)):
            close_tree(f"{name} alpha {alpha} frame {i}", x, y)
    # the kernels ran: the frame's pixels, and the overscan border's (project_border)
    assert (36, 64) in seen and (44, 72) in seen
    assert any(bool(torch.isinf(f.depth).any()) for f in orbit_frames)  # sky
    # the first frame's layer 1 is the shared empty one (K._empty_layer): it stays empty
    assert K._EMPTY_LAYERS
    for lay in K._EMPTY_LAYERS.values():
        assert not lay["valid"].any() and not lay["color"].any()
        assert bool(torch.isinf(lay["depth"]).all()) and lay["depth"].gt(0).all()


# ----------------------------------------------------------------------------- fused ops

def close_tree(name, a, b, contract=PIPELINE):
    """The kernels' result a agrees with the reference's b under ``contract`` (the fused
    ops': their CONTRACTS entry; whole pipelines: PIPELINE)."""
    check(name, a, b, contract)


def _hard_frames(h, w, seed):
    f = _frames(max(h, 3), w, seed)  # (cropped: _frames writes row h // 2 + 1)
    for k in ("d0", "d1", "mv1", "c1"):
        f[k] = f[k][:, :h].contiguous()
    f["h"] = h
    rng = np.random.default_rng(seed)
    g = torch.Generator().manual_seed(seed)
    f["dh"] = hard_depth(h, w, rng, 6.0) + 0.0
    c = torch.rand(3, h, w, generator=g) * 2 - 0.5
    c.view(-1)[:: 17] = NAN
    c.view(-1)[5:: 23] = INF
    c.view(-1)[7:: 29] = -INF
    f["ch"] = c
    m = f["mv1"].clone()
    m.view(-1)[:: 13] = NAN
    m.view(-1)[3:: 19] = INF
    m.view(-1)[4:: 31] = -3e9
    f["mh"] = m
    f["holes"] = torch.rand(1, h, w, generator=g) < 0.4
    return f


FUSED_SIZES = [(1, 1), (1, 9), (7, 1), (2, 2), (9, 14), (24, 40), (33, 51)]


@pytest.mark.parametrize("h,w", FUSED_SIZES)
def test_fused_gffe_ops_match_the_reference(h, w):
    f = _hard_frames(h, w, h * 100 + w)
    v = ~f["holes"]
    traj, dyn = G.track_history(f["d1"], f["mv1"], f["cam1"], f["cam0"], f["d0"], k=3)
    cases = []
    for dy in (dyn, None):
        cases.append(("dilate_trajectory", (traj, f["d1"], f["cam1"], dy)))
    for pos in (G.estimate_positions(traj, 0.5), G.unproject(f["dh"], f["cam1"])):
        cases.append(("warp_positions", (f["c1"], pos, f["cam_x"])))
        cases.append(("warp_positions", (f["ch"], pos, f["cam_x"], "bilinear", False)))
        # positions at their origin (P_0: the static pixels, sky, NaN / zero depths) keep
        # their pixels, the rest move (a still camera, and a moving one)
        for cam in (f["cam1"], f["cam_x"]):
            cases.append(("warp_positions", (f["ch"], pos, cam, "bilinear", True, None,
                                             traj[0])))
    for sc in (1, 2):
        prev = G.collect_background(f["c1"], f["d0"], ~dyn, f["cam0"], layer1_scale=sc)
        layers = G.collect_background(f["c1"], f["d1"], ~dyn, f["cam1"], prev, f["cam0"],
                                      layer1_scale=sc)
        for filt in ("nearest", "bilinear"):
            cases.append(("project_background", (layers, f["cam1"], f["cam_x"], f["holes"],
                                                 filt)))
    for fb in (0.1, 0.0, 0.5):
        cases.append(("push_pull_fill", (f["ch"], v, f["dh"], fb)))
    cases.append(("push_pull_fill", (f["ch"], torch.zeros_like(v), f["dh"])))
    _, dfill = G.push_pull_fill(f["c1"], v, torch.where(v, f["d1"], INF))
    for off in ("clamp", "skip"):
        for dq in (dfill, f["dh"]):
            cases.append(("reproject_fill", (f["ch"], v, dq, f["ch"], f["dh"], f["cam1"],
                                             f["cam_x"], 0.05, off)))
    for a in (0.5, 1.0, 3.0):
        cases.append(("vector_rule_fill", (f["ch"], v, f["dh"], f["mh"], f["ch"], f["dh"],
                                           f["mh"], a)))
    for name, args in cases:
        close_tree(f"{name} {h}x{w}", getattr(K, name)(*args), getattr(G, name)(*args),
                   CONTRACTS[name])


@pytest.mark.parametrize("h,w", [(37, 45), (64, 64), (33, 100), (70, 9), (9, 70)])
def test_push_pull_tiles_equal_the_frames_pyramid(h, w):
    """push_pull_fill by tiles (the pyramids of the aligned tiles with holes only) against
    the reference's pyramid of the frame, bit for bit: tiles of 2, 4, 8 and 32 pixels;
    single holes, a block across tile borders, holes in the last (partial) row and
    column; colours with NaN / +-inf, depths with sky, zero, negative and NaN; the tile
    path asserted taken. A tile of holes only, or whose valid pixels have no finite
    depth, sends the frame to the frame's pyramid (the same values)."""
    from fgcli.kernels.gffe import pp_tile_scan_kernel

    rng = np.random.default_rng(h * 1000 + w)
    g = torch.Generator().manual_seed(h * 1000 + w)
    c = torch.rand(3, h, w, generator=g) * 2 - 0.5
    c.view(-1)[::17] = NAN
    c.view(-1)[5::23] = INF
    c.view(-1)[7::29] = -INF
    d = torch.rand(1, h, w, generator=g) * 20 + 0.5
    flat = d.view(-1)
    for value in (0.0, -3.0, NAN, 1e-30, 3e38):
        flat[torch.randint(0, flat.numel(), (max(1, flat.numel() // 40),), generator=g)] = value
    v = torch.ones(1, h, w, dtype=torch.bool)
    v[0, rng.integers(0, h, 12), rng.integers(0, w, 12)] = False
    v[0, h // 2: h // 2 + 3, w // 2 - 2: w // 2 + 5] = False  # across tile borders
    v[0, h - 1, w - 1] = v[0, h - 1, 0] = v[0, 0, w - 1] = False
    taken = []
    for k in (1, 2, 3, 5):
        T = 1 << k
        if max(h, w) <= T:
            continue
        holes = np.empty((-(-h // T), -(-w // T)), dtype=np.uint8)
        ok = np.empty_like(holes)
        pp_tile_scan_kernel(d.numpy()[0], v.numpy()[0].view(np.uint8), k, holes, ok)
        taken.append(not np.any(holes & (1 - ok)))  # (a corner tile of one hole: not)
        for fb in (0.1, 0.0, 0.5):
            same_tree(f"push_pull tiles {h}x{w} k={k} fb={fb}",
                      K.push_pull_fill(c, v, d, fb, tile_k=k), G.push_pull_fill(c, v, d, fb))
    assert sum(taken) >= 2, taken
    # fallbacks: a tile of holes only; a tile whose valid pixels are all sky
    vb = v.clone()
    vb[0, :4, :4] = False
    ds = d.clone()
    ds[0, :4, :4] = INF
    vs = v.clone()
    vs[0, 1, 1] = False
    for args in ((c, vb, d), (c, vs, ds)):
        same_tree(f"push_pull fallback {h}x{w}", K.push_pull_fill(*args, 0.1, tile_k=2),
                  G.push_pull_fill(*args, 0.1))


@pytest.mark.parametrize("h,w", [(5, 200), (3, 64), (2, 65), (4, 129)])
def test_sample_where_skips_unselected_runs(h, w):
    """The fills' bilinear read (fgcli.kernels.ops._sample_where) skips runs of 64 pixels
    with nothing selected: the same result as where(sel, backward_warp(img, flow),
    base or 0) and where(sel, flow, fbase or 0) with sparse, dense, empty and edge-touching
    selections, and flow that is garbage (NaN, inf, huge) outside the selection."""
    from fgcli.kernels.ops import _sample_where
    from fgcli.ops.warp import backward_warp

    g = torch.Generator().manual_seed(h * 1000 + w)
    img = torch.rand(3, h, w, generator=g) * 4
    img.view(-1)[::29] = NAN
    img.view(-1)[::31] = INF
    flow = torch.randn(2, h, w, generator=g) * 3
    base = torch.rand(3, h, w, generator=g)
    fbase = torch.randn(2, h, w, generator=g)
    sparse = torch.zeros(1, h, w, dtype=torch.bool)
    sparse[0, ::2, w - 1] = True  # the last run of the row only
    sparse[0, h - 1, 0] = True
    sparse[0, 0, min(w - 1, 64)] = True  # the first pixel of the second run
    garbage = flow.clone()
    garbage[:, ~sparse[0]] = torch.tensor([NAN, INF, -INF, 1e30, 5e5])[
        torch.arange(int((~sparse[0]).sum())) % 5]
    for sel, fl in ((sparse, garbage), (sparse, flow),
                    (torch.rand(1, h, w, generator=g) < 0.5, flow),
                    (torch.zeros(1, h, w, dtype=torch.bool), garbage),
                    (torch.ones(1, h, w, dtype=torch.bool), flow)):
        for b, fb in ((None, None), (base, None), (base, fbase)):
            out, fout = _sample_where(img, fl, sel[0], base=b, fbase=fb)
            warped, _ = backward_warp(img, fl, "bilinear")
            ref = torch.where(sel, warped, b if b is not None else torch.zeros(()))
            fref = torch.where(sel, fl, fb if fb is not None else torch.zeros(()))
            close_tree(f"sample_where {h}x{w}", out, ref, CONTRACTS["warp_frames"])
            bits_equal(f"sample_where flow {h}x{w}", fout, fref)
            if b is not None:  # the fills' form: into their own base, no flow
                own = b.clone()
                o2, f2 = _sample_where(img, fl, sel[0], base=own, flow_out=False,
                                       in_place=True)
                assert o2 is own and f2 is None
                close_tree(f"sample_where in place {h}x{w}", o2, ref, CONTRACTS["warp_frames"])


@pytest.mark.parametrize("h,w", [(1, 1), (7, 1), (9, 14), (33, 51), (15, 200)])
def test_background_fill_matches_the_reference(h, w):
    """The bg_project stage's op (project_background + entering_surface + the selects);
    sparse holes too (runs of 64 pixels without one pass through, and only the cells the
    holes read are splatted, at full and half layer size), one at an odd last column and
    row (the half-size cell of a 1-pixel-wide block)."""
    f = _hard_frames(h, w, h * 100 + w + 7)
    traj, dyn = G.track_history(f["d1"], f["mv1"], f["cam1"], f["cam0"], f["d0"], k=3)
    wp = G.warp_positions(f["c1"], G.estimate_positions(traj, 0.5), f["cam_x"])
    sparse = torch.ones(1, h, w, dtype=torch.bool)
    sparse[0, ::4, ::37] = False
    sparse[0, h - 1, w - 1] = False
    frames = [(wp["color"], wp["depth"], wp["mv"], wp["valid"]),
              (f["ch"], f["dh"], f["mh"], ~f["holes"]),
              (f["ch"], f["dh"], f["mh"], sparse)]
    for sc in (1, 2):
        prev = G.collect_background(f["c1"], f["d0"], ~dyn, f["cam0"], layer1_scale=sc)
        layers = G.collect_background(f["c1"], f["d1"], ~dyn, f["cam1"], prev, f["cam0"],
                                      layer1_scale=sc)
        # a sequence's first frame (layer 1 empty: not projected at all) and no static
        # pixel (both layers empty)
        first = G.collect_background(f["c1"], f["d1"], ~dyn, f["cam1"], layer1_scale=sc)
        assert not bool(first[1]["valid"].any())
        none = [dict(lay, valid=torch.zeros_like(lay["valid"])) for lay in layers]
        for li, lays in enumerate((layers, first, none)):
            for filt in ("nearest", "bilinear"):
                for ent, em, a in ((False, False, 0.5), (True, False, 3.0),
                                   (True, True, 0.5), (True, True, 3.0)):
                    for i, fr in enumerate(frames):
                        args = fr + (lays, f["cam1"], f["cam_x"], filt, f["ch"], f["dh"],
                                     f["mh"], a, ent, em)
                        same_tree(f"background_fill {h}x{w} {sc} {li} {filt} {ent} {em} {a} "
                                  f"{i}", K.background_fill(*args), G.background_fill(*args))


@pytest.mark.parametrize("sc", [1, 2])
def test_background_fill_sparse_holes_match_the_reference(sc):
    """Sparse holes over well-covered layers (so that most holes are filled): runs of 64
    pixels without a hole pass through, and only the layer cells the holes read are
    splatted (layer 1 at half size: the 2 x 2 block of a cell, odd last row and column)."""
    h, w = 15, 203
    f = _hard_frames(h, w, 11)
    g = torch.Generator().manual_seed(5)
    h2, w2 = (h, w) if sc == 1 else G._half(h, w)
    layers = []
    for lh, lw, dz in ((h, w, 4.0), (h2, w2, 9.0)):
        layers.append({"color": torch.rand(3, lh, lw, generator=g),
                       "depth": dz + torch.rand(1, lh, lw, generator=g),
                       "valid": torch.rand(1, lh, lw, generator=g) < 0.9})
    sparse = torch.ones(1, h, w, dtype=torch.bool)
    sparse[0, 1::4, 1::37] = False  # odd rows and columns: the second pixel of a cell
    sparse[0, 2, 70:75] = False
    sparse[0, h - 1, w - 1] = False
    from unittest import mock

    def poisoned(*shape, dtype=torch.float32):
        """torch.empty with garbage that would show: the splats' rows without a hole are
        left unwritten (splat_min_kernel's want path), so nothing may read them"""
        t = torch.empty(shape, dtype=dtype)
        return t.fill_(True if dtype == torch.bool else
                       float("nan") if dtype.is_floating_point else 1 << 40)

    for filt in ("nearest", "bilinear"):
        args = (f["ch"], f["dh"], f["mh"], sparse, layers, f["cam1"], f["cam1"], filt,
                f["ch"], f["dh"], f["mh"], 0.5, True, True)
        k, r = K.background_fill(*args), G.background_fill(*args)
        same_tree(f"background_fill sparse {sc} {filt}", k, r)
        with mock.patch.object(K, "_empty", side_effect=poisoned):
            same_tree(f"background_fill sparse, garbage memory {sc} {filt}",
                      K.background_fill(*args), r)
        filled = int((r[3] & ~sparse).sum())
        assert filled >= 0.7 * int((~sparse).sum()), filled  # the holes did take fragments


@pytest.mark.parametrize("h,w", [(1, 1), (7, 1), (9, 14), (33, 51)])
def test_track_history_matches_the_reference(h, w):
    """track_history's kernels (static test, match search, trajectory) with depth0 and / or
    a previous trajectory, every lookup, k, and the fallback (tol 0: every match misses)."""
    f = _hard_frames(h, w, h * 100 + w + 11)
    prev3, _ = G.track_history(f["d1"], f["mv1"], f["cam1"], f["cam0"], f["d0"], k=3)
    prev2, _ = G.track_history(f["d0"], f["mv1"], f["cam0"], f["cam1"], f["d1"], k=2)
    for d1, mv in ((f["d1"], f["mv1"]), (f["dh"], f["mh"]), (f["dh"], f["mv1"] * 0.05)):
        for d0, prev in ((f["d0"], None), (f["dh"].flip(-1).contiguous(), prev3),
                         (None, prev3), (f["d0"], prev2), (None, prev2)):
            for k in (2, 3, 4):
                for lookup, thr, tol in (("match", 0.5, 0.1), ("match", 0.0, 0.0),
                                         ("nearest", 3.0, 0.1)):
                    args = (d1, mv, f["cam1"], f["cam0"], d0, prev, k, thr, "mv", lookup, tol)
                    same_tree(f"track_history {h}x{w} k{k} {lookup} {thr} {d0 is None} "
                              f"{None if prev is None else prev.shape[0]}",
                              K.track_history(*args), G.track_history(*args))


def test_median_depth_matches_the_reference():
    """The window's median (an exact selection on the float32 bits) vs torch.nanmedian:
    no finite positive value (NaN), ties, even and odd counts, extreme values, smooth
    depth maps (the second pass's block skipping)."""
    rng = np.random.default_rng(0)
    cases = [torch.tensor([[[NAN]]]), torch.full((1, 3, 4), INF), torch.zeros(1, 2, 2),
             torch.tensor([[[2.0, 1.0]]]), torch.tensor([[[1e-45, 3e38, 5.0, 5.0]]])]
    g = torch.Generator().manual_seed(0)
    for h, w in [(1, 1), (1, 9), (7, 1), (9, 14), (33, 51), (75, 97)]:  # (the last: blocks)
        for s in (50.0, 1e-3, 1e30):
            cases.append(hard_depth(h, w, rng, s))
        cases.append((torch.rand(1, h, w, generator=g) * 4).round())
    # smooth depths (most blocks of 1024 pixels cannot hold the median's top bits: the
    # second pass skips them), with sky rows, a NaN and a spike
    y, x = torch.meshgrid(torch.arange(120.0), torch.arange(300.0), indexing="ij")
    for z in (1.0 + y * 0.05 + x * 1e-4, 100.0 - y * 0.7, 2.0 ** (y / 8.0)):
        z = z[None].clone()
        z[:, :17] = INF
        z[0, 60, 5] = NAN
        z[0, 90, 200] = 1e30
        cases += [z, z[:, :, :150].contiguous(), z.flip(-1).contiguous()]
    # flat planes (a run of one bin through whole blocks and on across them), blocks of
    # sky between them, and one spike
    z = torch.full((1, 40, 300), 7.0)
    z[0, 10:14] = INF
    z[0, 22:] = 3.0
    z[0, 5, 7] = 9.0
    cases += [z, z[:, :, :171].contiguous(), z[:, 3:].contiguous()]
    for i, c in enumerate(cases):
        a, b = K.median_depth(c), G.median_depth(c)
        assert (math.isnan(a) and math.isnan(b)) or a == b, (i, a, b)


@pytest.mark.parametrize("h,w", [(1, 1), (7, 1), (9, 14), (33, 51)])
def test_collect_background_matches_the_reference(h, w):
    """collect_background's kernels: first frame and with previous layers of either
    layer-1 size, into either size, hard depths and colours, several margins."""
    f = _hard_frames(h, w, h * 100 + w + 5)
    traj, dyn = G.track_history(f["d1"], f["mv1"], f["cam1"], f["cam0"], f["d0"], k=3)
    for sp in (1, 2):
        prev = G.collect_background(f["ch"], f["d0"], ~dyn, f["cam0"], layer1_scale=sp)
        prev = G.collect_background(f["c1"], f["dh"], ~f["holes"], f["cam0"], prev, f["cam1"],
                                    layer1_scale=sp)
        for sc in (1, 2):
            for d1, st in ((f["d1"], ~dyn), (f["dh"], ~f["holes"])):
                for tol in (0.02, 0.5):
                    for pl in (prev, None):
                        args = (f["ch"], d1, st, f["cam1"], pl, f["cam0"], tol, False, sc)
                        same_tree(f"collect_background {h}x{w} {sp} {sc} {tol}",
                                  K.collect_background(*args), G.collect_background(*args))


@pytest.mark.parametrize("h,w", [(1, 1), (7, 1), (9, 14), (33, 51), (12, 64)])
def test_dilated_positions_matches_the_reference(h, w):
    """The position stage's dilation + Eq. 1 in one kernel: k 2-4, linear / quadratic,
    with and without the dynamic mask, several alphas. The dynamic masks include ones with
    dynamic pixels in a few rows only (the kernel dilates the rows beside them only), at
    the frame's first and last rows, and none."""
    f = _hard_frames(h, w, h * 100 + w + 3)
    for k in (2, 3, 4):
        traj, dyn = G.track_history(f["dh"], f["mh"], f["cam1"], f["cam0"], f["d0"], k=k)
        sparse = torch.zeros_like(dyn)
        sparse[:, h // 2] = True
        sparse[:, h - 1, w // 2:] = True
        edge = torch.zeros_like(dyn)
        edge[:, 0, :w // 2 + 1] = True
        masks = (dyn, None, sparse, edge, torch.zeros_like(dyn), sparse | dyn)
        for d1 in (f["d1"], f["dh"]):
            for dd in masks:
                for a, motion in ((0.5, "linear"), (3.0, "linear"), (0.5, "quadratic"),
                                  (1.0, "quadratic")):
                    args = (traj, d1, f["cam1"], dd, a, motion)
                    same_tree(f"dilated_positions {h}x{w} k{k} {a} {motion}",
                              K.dilated_positions(*args), G.dilated_positions(*args))


@pytest.mark.parametrize("h,w", [(12, 40), (33, 51), (20, 130), (9, 300)])
def test_fill_holes_reprojects_the_rows_with_holes_only(h, w):
    """fill_holes computes the proxy points of rows with holes only (the other rows' are
    never read): bit-identical to the same kernels over every row (the reference's
    composition of reproject_fill's and push_pull_fill's kernels), with holes in a few
    rows, sky in rows with and without holes (the sky pass's sqrt spans the same rows),
    and no hole at all."""
    f = _hard_frames(h, w, h * 100 + w + 21)
    d = f["d1"].clone()
    d[0, : h // 3] = INF  # sky rows, some of them with holes
    v = torch.ones(1, h, w, dtype=torch.bool)
    for r in (1, h // 2, h - 1):
        v[0, r, (r * 7) % w: (r * 7) % w + 5] = False
    parts = (K.project_border, K.push_pull_fill, K.reproject_fill)
    for vv in (v, torch.ones_like(v)):
        for off in ("clamp", "skip"):
            args = (f["c1"], d, f["mv1"], vv, 0.1, "reproject", off, True, f["ch"], f["dh"],
                    f["cam1"], f["cam_x"], None)
            same_tree(f"fill_holes rows {h}x{w} {off}", K.fill_holes(*args),
                      G.fill_holes(*args, parts=parts))


@pytest.mark.parametrize("h,w", [(1, 1), (7, 1), (9, 14), (33, 51)])
def test_fill_holes_matches_the_reference(h, w):
    """The hole-fill stage's op: push-pull, the vectors and the reprojection (kernels),
    with a border / push_pull only / without cameras (the composition of the ops)."""
    f = _hard_frames(h, w, h * 100 + w + 13)
    b = 2
    border = {"origin": (-b, -b), "color": torch.rand(3, h + 2 * b, w + 2 * b),
              "depth": torch.nn.functional.pad(f["d1"], (b, b, b, b), value=5.0)}
    v = ~f["holes"]
    for col, dep, mv in ((f["ch"], f["dh"], f["mh"]), (f["c1"], f["d1"], f["mv1"])):
        for fb, mode, off, bd, cams in ((0.1, "reproject", "clamp", None, True),
                                        (0.0, "reproject", "skip", None, True),
                                        (0.5, "push_pull", "clamp", None, True),
                                        (0.1, "reproject", "clamp", border, True),
                                        (0.1, "reproject", "clamp", None, False)):
            c1, cx = (f["cam1"], f["cam_x"]) if cams else (None, None)
            args = (col, dep, mv, v, fb, mode, off, True, f["ch"], f["dh"], c1, cx, bd)
            close_tree(f"fill_holes {h}x{w} {fb} {mode} {off} {bd is not None} {cams}",
                      K.fill_holes(*args), G.fill_holes(*args), CONTRACTS["fill_holes"])


@pytest.mark.parametrize("h,w,sc", [(1, 1, 1.0), (9, 14, 1.0), (33, 51, 1.0), (33, 51, 2.0)])
def test_splat_min_with_want_matches_the_full_splat_at_want_cells(h, w, sc):
    """The want path sets and reads buf at want cells only: there it must give what the
    full splat (itself checked against the torch reference) gives; empty at the other
    cells of the rows with a want cell; the rows without one are not written."""
    g = torch.Generator().manual_seed(h * 7 + w)
    hs, ws = (h, w) if sc == 1.0 else (2 * h, 2 * w)
    th, tw = (h, w)
    px = torch.rand(hs, ws, generator=g) * (tw + 4) * sc - 2 * sc
    py = torch.rand(hs, ws, generator=g) * (th + 4) * sc - 2 * sc
    dn = torch.rand(1, hs, ws, generator=g) * 10
    dn.view(-1)[:: 11] = NAN
    dn.view(-1)[4:: 17] = INF
    use = torch.rand(hs, ws, generator=g) < 0.8
    ref_src, ref_dep = G._splat_min(torch.floor(px / sc), torch.floor(py / sc), dn, use, th, tw)
    full_src, full_dep = K._splat_min(px, py, sc, dn, use, th, tw)
    assert torch.equal(full_src.reshape(th, tw), ref_src.reshape(th, tw))
    assert torch.equal(full_dep.reshape(th, tw), ref_dep.reshape(th, tw))
    from unittest import mock

    for frac in (0.0, 0.02, 0.3, 1.0):
        want = (np.random.default_rng(w).random((th, tw)) < frac).astype(np.uint8)
        want[th // 2] = 0  # (a row without a want cell)
        # the outputs' memory filled with a marker first: the rows without a want cell
        # must keep it (not written), the others must not
        marks = (torch.full((th, tw), 12345, dtype=torch.int64), torch.full((th, tw), -7.0))
        with mock.patch.object(K, "_empty", side_effect=[t.clone() for t in marks]):
            src, dep = K._splat_min(px, py, sc, dn, use, th, tw, want)
        src, dep = src.reshape(th, tw), dep.reshape(th, tw)
        m = torch.from_numpy(want.astype(bool))
        rows = m.any(dim=1)
        assert torch.equal(src[m], full_src.reshape(th, tw)[m])
        assert torch.equal(dep[m], full_dep.reshape(th, tw)[m])
        other = rows[:, None] & ~m
        assert (src[other] == -1).all() and torch.isinf(dep[other]).all()
        assert (src[~rows] == 12345).all() and (dep[~rows] == -7.0).all()


@pytest.mark.parametrize("h,w", [(1, 1), (9, 14), (33, 51), (15, 200), (70, 90)])
def test_hole_fills_in_place_write_scratch_only(h, w):
    """The hole stages' ops with in_place=True (vector_rule_fill, background_fill,
    fill_holes, push_pull_fill's tile path): where the colour, depth and vectors are marked
    scratch (fgcli.ops._util.mark_scratch) the filled holes are written into them (the
    results are those tensors) with the same bits as without in_place, and the reference's
    values; unmarked inputs, or in_place=False, are never changed. Colours with NaN / inf
    at valid pixels (the push-pull sanitises them after its tiles read them), sparse holes
    (the tile path) and dense ones (the frame's pyramid: copies)."""
    from fgcli.ops._util import is_scratch, mark_scratch, unmarked

    f = _hard_frames(h, w, h * 100 + w + 3)
    traj, dyn = G.track_history(f["d1"], f["mv1"], f["cam1"], f["cam0"], f["d0"], k=3)
    wp = G.warp_positions(f["c1"], G.estimate_positions(traj, 0.5), f["cam_x"])
    sparse = torch.ones(1, h, w, dtype=torch.bool)
    sparse[0, ::3, ::29] = False
    left = torch.ones(1, h, w, dtype=torch.bool)  # (holes in the rows' first run of 64
    left[0, 1::3, 2:9] = False  # pixels only: the others hold none)
    prev = G.collect_background(f["c1"], f["d0"], ~dyn, f["cam0"])
    layers = G.collect_background(f["c1"], f["d1"], ~dyn, f["cam1"], prev, f["cam0"])
    frames = [(wp["color"], wp["depth"], wp["mv"], wp["valid"]),
              (f["ch"], f["dh"], f["mh"], ~f["holes"]),
              (f["ch"], f["d1"], f["mh"], sparse), (f["ch"], f["d1"], f["mh"], left)]
    took_path = set()
    for i, (c, d, m, v) in enumerate(frames):
        calls = {
            "vector_rule_fill": (lambda c, d, m: (c, v, d, m, f["ch"], f["dh"], f["mh"], 1.5),
                                 3),
            "background_fill": (lambda c, d, m: (c, d, m, v, layers, f["cam1"], f["cam_x"],
                                                 "bilinear", f["ch"], f["dh"], f["mh"], 0.5,
                                                 True, True), 3),
            "fill_holes": (lambda c, d, m: (c, d, m, v, 0.1, "reproject", "clamp", True,
                                            f["ch"], f["dh"], f["cam1"], f["cam_x"], None), 3),
            "push_pull_fill": (lambda c, d, m: (c, v, d, 0.1), 2)}
        for name, (args, n) in calls.items():
            base = getattr(K, name)(*args(*[x.clone() for x in (c, d, m)]))
            close_tree(f"{name} {h}x{w} {i} reference", base, getattr(G, name)(*args(c, d, m)),
                       CONTRACTS[name])
            for marked in (True, False):
                for inp in (True, False):
                    planes = [x.clone() for x in (c, d, m)]
                    if marked:
                        mark_scratch(*planes)
                    keep = [x.clone() for x in planes]
                    out = getattr(K, name)(*args(*planes), in_place=inp)
                    tag = f"{name} {h}x{w} {i} marked={marked} in_place={inp}"
                    same_tree(tag, out, base)
                    same = [a is b for a, b in zip(out[:n], planes)]
                    if any(same):
                        assert marked and inp and all(same), tag
                        took_path.add(name)
                    else:
                        for a, b in zip(planes, keep):
                            bits_equal(tag, a, b)
                    if name in ("vector_rule_fill", "background_fill"):  # (results: scratch)
                        assert all(is_scratch(x) for x in out[:n]), tag
                    # an unmarked alias (the pipeline's measuring runs) is left alone
                    if marked and inp:
                        planes = mark_scratch(*[x.clone() for x in (c, d, m)])
                        keep = [x.clone() for x in planes]
                        getattr(K, name)(*args(*[unmarked(x) for x in planes]), in_place=True)
                        for a, b in zip(planes, keep):
                            bits_equal(tag, a, b)
    if h * w > 1:  # the in-place path was taken, by every op (sparse holes: the tile path)
        assert took_path == {"vector_rule_fill", "background_fill", "fill_holes",
                             "push_pull_fill"} or max(h, w) <= 32, took_path


@pytest.mark.parametrize("hs,ws,h,w,sc", [(1, 1, 1, 1, 1.0), (9, 14, 9, 14, 1.0),
                                          (33, 51, 33, 51, 1.0), (33, 51, 17, 26, 2.0),
                                          (60, 80, 60, 80, 1.0)])
def test_sparse_splat_fill_equals_the_dense_pair(hs, ws, h, w, sc):
    """collect_background's splat + layer fill: the sparse kernel (the used fragments
    alone, serially) gives the dense pair's layer bit for bit: fragments off screen, NaN /
    negative / inf depths, many on one cell (the least depth wins, then the lower index),
    a layer already valid in places (kept), every use density."""
    g = torch.Generator().manual_seed(hs * 31 + ws + int(sc))
    px = torch.rand(hs, ws, generator=g) * (w * sc + 4) - 2
    py = torch.rand(hs, ws, generator=g) * (h * sc + 4) - 2
    px.view(-1)[::5] = torch.floor(px.view(-1)[::5] / 4) * 4  # clusters on few cells
    py.view(-1)[::5] = 1.0
    dn = torch.rand(hs, ws, generator=g) * 10
    dn.view(-1)[::7] = 5.0  # equal depths: the lower index wins
    dn.view(-1)[1::11] = NAN
    dn.view(-1)[2::13] = -1.0
    dn.view(-1)[4::17] = INF
    pc = torch.rand(3, hs, ws, generator=g)
    for dens in (0.0, 0.02, 0.3, 1.0):
        use = (torch.rand(hs, ws, generator=g) < dens).to(torch.uint8).numpy()
        outs = []
        for sparse in (True, False):
            lay = G.empty_layer(h, w, "cpu")
            lay["valid"].view(-1)[::9] = True
            lay["depth"].view(-1)[::9] = 2.5
            lay["color"][:, ::2] = 0.25
            K._splat_fill(px, py, sc, dn, use, h, w, pc.numpy(), lay["color"].numpy(),
                          lay["depth"].numpy()[0], lay["valid"].numpy()[0].view(np.uint8),
                          sparse=sparse)
            outs.append(lay)
        same_tree(f"splat fill {hs}x{ws} -> {h}x{w} {dens}", outs[0], outs[1])
        if dens >= 0.3 and hs * ws > 1:  # (fragments did fill cells)
            assert int(outs[0]["valid"].sum()) > len(range(0, h * w, 9))
