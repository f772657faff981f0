"""GFFE geometry-aware extrapolation (fgcli/ops/gffe.py, fgcli/stages/gffe.py,
pipelines/gffe-extrap.toml): ops known answers, hard cases, state across frames and cuts,
and chunked runs byte-identical to one run."""
from __future__ import annotations

import math
import os
import shutil

import numpy as np
import pytest
import torch
from click.testing import CliRunner

from fgcli import pipeline as pl
from fgcli.cli import cli
from fgcli.errors import InputError
from fgcli.frame import Camera, Frame
from fgcli.kernels.contract import PIPELINE, check
from fgcli.ops.gffe import (collect_background, estimate_positions, extrapolate_camera,
                            look_at, project, project_background, push_pull_fill,
                            render_window, track_history, unproject, warp_positions)
from fgcli.runner import RunState, make_ctx

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ORBIT = os.path.join(ROOT, "sample_data", "orbit", "input")
H, W, D = 24, 32, 10.0


def proj(fov=50.0, aspect=W / H, near=0.05, far=1000.0):
    f = 1.0 / math.tan(math.radians(fov / 2))
    return np.array([[f / aspect, 0, 0, 0], [0, f, 0, 0],
                     [0, 0, -(far + near) / (far - near), -2 * far * near / (far - near)],
                     [0, 0, -1, 0]])


def cam_at(x, y=0.0, z=0.0):
    return Camera(look_at([x, y, z], [0, 0, -1], [0, 1, 0]), proj())


def shift_per_frame(dx):
    """Pixels a fronto-parallel plane at depth D moves when the camera moves dx in x."""
    return proj()[0, 0] * dx / D * W / 2


def plane_frame(n, cam_x, color, depth=D, mv_x=0.0):
    return Frame(number=n, color=color, depth=torch.full((1, H, W), float(depth)),
                 mv=torch.stack([torch.full((H, W), float(mv_x)), torch.zeros(H, W)]),
                 camera=cam_at(cam_x))


# ------------------------------------------------------------------------------- cameras

def test_unproject_project_round_trip_and_sky_is_finite():
    g = torch.Generator().manual_seed(0)
    depth = 1 + 20 * torch.rand(1, H, W, generator=g)
    depth[0, :3] = math.inf
    depth[0, 5, 5] = 0.0
    depth[0, 6, 6] = float("nan")
    cam = cam_at(0.3, 1.0, 2.0)
    X = unproject(depth, cam)
    assert X.shape == (4, H, W) and torch.isfinite(X).all()
    assert (X[3, :3] == 0).all() and X[:, 5, 5].abs().sum() == 0 and X[:, 6, 6].abs().sum() == 0
    px, py, d, ok = project(X, cam, (H, W))
    xs = torch.arange(W) + 0.5
    good = ok & torch.isfinite(depth[0])
    assert torch.allclose(px[good], xs.expand(H, W)[good], atol=2e-3)
    assert torch.allclose(d[good], depth[0][good], rtol=1e-4)
    assert torch.isinf(d[:3]).all() and ok[:3].all()  # sky: a direction, on screen
    assert not ok[5, 5] and not ok[6, 6]


def test_camera_extrapolation_is_exact_for_linear_motion():
    c0, c1, c2 = cam_at(0.0), cam_at(0.4), cam_at(0.6)
    v, p = extrapolate_camera(c0, c1, 0.5)
    assert np.allclose(v, c2.world_to_camera, atol=1e-9) and np.array_equal(p, c1.projection)
    v, _ = extrapolate_camera(c1, c1, 0.5)  # static: the current matrix, exactly
    assert np.array_equal(v, c1.world_to_camera)
    v, _ = extrapolate_camera(None, c1, 0.5)  # no history
    assert np.array_equal(v, c1.world_to_camera)


def test_render_window_grows_toward_the_camera_motion():
    c0, c1 = cam_at(0.0), cam_at(0.5)
    cx = extrapolate_camera(c0, c1, 0.5)
    u0, v0, u1, v1 = render_window(c1, cx, D)
    assert u0 == -1.0 and v0 == -1.0 and v1 == 1.0 and u1 > 1.0
    # 0.25 units at depth 10 over a half-width of D / P00: exact
    assert u1 == pytest.approx(1 + 0.25 / (D / proj()[0, 0]), rel=1e-6)
    assert render_window(c1, extrapolate_camera(c1, c1, 0.5), D) == (-1.0, -1.0, 1.0, 1.0)


# ------------------------------------------------------------------------------ history

def test_static_scene_with_moving_camera_has_no_dynamic_pixels():
    dx = 2 * D * 4 / (proj()[0, 0] * W)  # 4 px per frame
    f0 = plane_frame(0, 0.0, torch.rand(3, H, W))
    f1 = plane_frame(1, dx, torch.rand(3, H, W), mv_x=shift_per_frame(dx))
    traj, dyn = track_history(f1.depth, f1.mv, f1.camera, f0.camera, f0.depth, k=3)
    assert not dyn.any()
    assert torch.equal(traj[0], traj[1]) and torch.equal(traj[1], traj[2])


def test_moving_object_is_dynamic_and_its_trajectory_is_its_previous_position():
    cam = cam_at(0.0)
    d = torch.full((1, H, W), D)
    mv = torch.zeros(2, H, W)
    mv[0, 8:16, 8:16] = -3.0  # the patch was 3 px to the left: it moves right
    traj, dyn = track_history(d, mv, cam, cam, d, k=2, threshold=0.5)
    assert dyn[0, 8:16, 8:16].all() and dyn.sum() == 64
    X = unproject(d, cam)
    assert torch.allclose(traj[1][:, 8:16, 8:16], X[:, 8:16, 5:13], atol=1e-4)
    # Eq. 1: NP = P0 + alpha (P0 - P1): half a frame = 1.5 px further right
    npos = estimate_positions(traj, 0.5)
    px, _, _, _ = project(npos, cam, (H, W))
    assert torch.allclose(px[8:16, 8:16], (torch.arange(8, 16) + 0.5 + 1.5).expand(8, 8),
                          atol=1e-3)


@pytest.mark.parametrize("shift", [0, 3])
def test_silhouette_pixel_history_reads_its_own_surface_not_the_one_behind(shift):
    """A moving object's edge pixel whose vector ends just off the object in frame 0 (x'
    lands on the wall behind it): the nearest-pixel lookup (the paper) reads the wall's
    depth and the pixel lags behind its object; lookup=match reads the object's depth from
    a 3x3 neighbour, or, when none of them shows it (shift=3: the object sits further
    away in frame 0), keeps the pixel's current depth at x' (screen-space motion)."""
    cam = cam_at(0.0)
    d1 = torch.full((1, H, W), 2 * D)
    d1[0, 8:16, 12:20] = D  # the object now
    d0 = torch.full((1, H, W), 2 * D)
    d0[0, 8:16, 10 + shift:18 + shift] = D  # frame 0: object 3.6 px to the left (shift 0)
    mv = torch.zeros(2, H, W)
    mv[0, 8:16, 12:20] = -3.6  # pixel 12 (centre 12.5) came from x' = 8.9: the wall pixel 8
    want = 12.5 + 3.6  # alpha 1: one more step of 3.6 px
    for lookup, ok in (("match", True), ("nearest", False)):
        traj, dyn = track_history(d1, mv, cam, cam, d0, k=2, lookup=lookup)
        assert dyn[0, 8:16, 12:20].all()
        px, _, _, _ = project(estimate_positions(traj, 1.0), cam, (H, W))
        err = (px[8:16, 12] - want).abs()
        if ok:
            assert float(err.max()) < 1e-2
            # the object's inner pixels, whose x' lies on it, are the same either way
            assert torch.allclose(px[8:16, 13:20], (torch.arange(13, 20) + 0.5 + 3.6)
                                  .expand(8, 7), atol=1e-2)
        else:
            assert float(err.min()) > 0.5  # the paper's lookup: the edge pixel lags


def test_dilation_moves_an_edge_pixel_with_its_object():
    """position.dilate=full: a background-depth pixel beside a moving object takes the
    object's depth and motion (Mob-FGSR's dilation in world space); a pixel with no nearer
    neighbour keeps its own position and trajectory. dilate=dynamic: only static pixels
    beside a dynamic winner."""
    from fgcli.ops.gffe import dilate_trajectory

    cam = cam_at(0.0)
    d = torch.full((1, H, W), 2 * D)
    d[0, 8:16, 8:16] = D
    mv = torch.zeros(2, H, W)
    mv[0, 8:16, 8:16] = -2.0
    traj, _ = track_history(d, mv, cam, cam, d.roll(-2, -1), k=2)
    out = dilate_trajectory(traj, d, cam)
    px, _, dep, _ = project(estimate_positions(out, 1.0), cam, (H, W))
    assert abs(float(px[10, 16]) - (16.5 + 2.0)) < 1e-2  # the edge pixel moved with it
    assert abs(float(dep[10, 16]) - D) < 1e-3
    assert torch.equal(out[:, :, :, 20:], traj[:, :, :, 20:])  # far from the object
    assert torch.allclose(px[8:16, 8:16], (torch.arange(8, 16) + 0.5 + 2.0).expand(8, 8),
                          atol=1e-2)
    # dilate=dynamic: the same rim pixel (static) follows its dynamic neighbour; a static
    # pixel beside a nearer static one (the step at column 20) keeps its own position
    d[0, :, 20:] = 1.5 * D
    d0 = d.roll(-2, -1).clone()
    d0[0, :, 18:] = d[0, :, 18:]  # the static step did not move
    traj, dyn = track_history(d, mv, cam, cam, d0, k=2)
    assert dyn[0, 8:16, 8:16].all() and not dyn[0, :, 16:].any()
    out = dilate_trajectory(traj, d, cam, dyn)
    px, _, _, _ = project(estimate_positions(out, 1.0), cam, (H, W))
    assert abs(float(px[10, 16]) - (16.5 + 2.0)) < 1e-2
    assert torch.equal(out[:, :, :, 18:], traj[:, :, :, 18:])
    assert torch.equal(out[:, :, 8:16, 8:16], traj[:, :, 8:16, 8:16])  # dynamic: its own


def test_history_keeps_as_many_positions_as_the_position_stage_reads():
    """k = 0 (the pipeline file's): two positions for Eq. 1, three for motion=quadratic; an
    explicit k too short for the position stage is a usage error naming the file and line."""
    from fgcli.errors import UsageError

    def k_of(variant):
        return [st.k for _, st in pl.load(variant).build("extrap") if st.name == "gffe_history"]

    assert k_of("gffe-extrap") == [2]
    assert k_of("gffe-extrap:motion=quadratic") == [3]
    assert k_of("gffe-extrap:history.k=4") == [4]
    for bad in ("gffe-extrap:motion=quadratic,history.k=2", "gffe-extrap:history.k=1"):
        with pytest.raises(UsageError, match=r"gffe-extrap\.toml:\d+: stage 'gffe_history'"):
            pl.load(bad)


def test_quadratic_positions_are_exact_for_constant_acceleration():
    p = lambda t: torch.tensor([t * t, 2.0 * t, 0.0, 1.0]).view(4, 1, 1)  # noqa: E731
    traj = torch.stack([p(0.0), p(-1.0), p(-2.0)])
    assert torch.allclose(estimate_positions(traj, 0.5, "quadratic"), p(0.5), atol=1e-6)
    lin = estimate_positions(traj, 0.5, "linear")
    assert torch.allclose(lin, torch.tensor([-0.5, 1.0, 0.0, 1.0]).view(4, 1, 1))


# -------------------------------------------------------------------------------- warp

@pytest.mark.parametrize("filt", ["nearest", "bilinear"])
def test_static_scene_moving_camera_extrapolates_exactly_where_geometry_is_visible(filt):
    dx = 2 * D * 4 / (proj()[0, 0] * W)  # 4 px per frame -> 2 px at alpha 0.5
    color = torch.rand(3, H, W, generator=torch.Generator().manual_seed(3))
    f0 = plane_frame(0, 0.0, torch.zeros(3, H, W))
    f1 = plane_frame(1, dx, color, mv_x=4.0)
    traj, _ = track_history(f1.depth, f1.mv, f1.camera, f0.camera, f0.depth)
    cx = extrapolate_camera(f0.camera, f1.camera, 0.5)
    out = warp_positions(color, estimate_positions(traj, 0.5), cx, filt)
    # content moves 2 px left: target column x shows frame 1's column x + 2
    assert torch.allclose(out["color"][:, :, :W - 2], color[:, :, 2:], atol=2e-3)
    assert out["valid"][:, :, :W - 2].all() and not out["valid"][:, :, W - 2:].any()
    assert torch.allclose(out["mv"][0, :, :W - 2], torch.full((H, W - 2), 2.0), atol=1e-3)
    assert torch.allclose(out["depth"][:, :, :W - 2], torch.full((1, H, W - 2), D), rtol=1e-5)


def test_a_still_camera_keeps_the_positions_at_their_origin_on_their_pixels():
    """origin: a position equal to its pixel's P_0 under frame 1's camera stays on its
    pixel exactly (zero vector, frame 1's colour as it is), where the projection's float32
    round trip alone moves it by rounding; a moved position still moves."""
    g = torch.Generator().manual_seed(5)
    cam = cam_at(0.3, 0.2, 1.0)  # (off the origin: the round trip rounds)
    # a sloped surface (random depths would be cracks to the gap fill), sky, and a near
    # block that moves 3 px right, in front of where it lands
    ys, xs = torch.meshgrid(torch.arange(H), torch.arange(W), indexing="ij")
    depth = (4.0 + 0.37 * xs + 0.21 * ys).float()[None]
    depth[0, :2] = math.inf  # sky: a direction, at rest too
    depth[0, 10:14, 5:9] = 1.0
    color = torch.rand(3, H, W, generator=g)
    X = unproject(depth, cam)
    cx = extrapolate_camera(cam, cam, 0.5)  # a still camera: frame 1's matrices
    moved = X.clone()
    px, py, _, _ = project(X, cam, (H, W))
    moved[:, 10:14, 5:9] = unproject(depth, cam, px + 3.0, py)[:, 10:14, 5:9]
    for filt in ("bilinear", "nearest"):
        out = warp_positions(color, moved, cx, filt, origin=X)
        rest = torch.ones(H, W, dtype=torch.bool)
        rest[8:16, 4:14] = False  # the moved block, where it lands, the cracks filled
        assert (out["mv"][:, rest] == 0).all()
        assert torch.equal(out["color"][:, rest], color[:, rest])
        assert torch.equal(out["valid"][0, rest], torch.ones_like(rest[rest]))
        # the moved block: 3 px right, its vectors back toward frame 1
        assert torch.allclose(out["mv"][0, 10:14, 8:12], torch.full((4, 4), -3.0), atol=1e-3)
        assert torch.allclose(out["color"][:, 10:14, 8:12], color[:, 10:14, 5:9], atol=2e-3)
    # without the origin the round trip's rounding moves pixels off their centres
    free = warp_positions(color, X, cx, "bilinear")
    assert (free["mv"] != 0).any()
    with pytest.raises(ValueError, match="origin"):
        warp_positions(color, X, cx, origin=X[:, :-1])


def test_a_still_camera_leaves_the_static_pixels_of_the_extrapolation_exact():
    """The pipeline passes the warp frame 1's P_0 as the origin when the camera did not
    move: every static pixel away from the moving block keeps frame 1's colour and a zero
    vector, on the torch and numba backends alike."""
    g = torch.Generator().manual_seed(6)
    depth = 2.0 + 30.0 * torch.rand(1, H, W, generator=g)
    frames = []
    for n in range(3):
        color = torch.rand(3, H, W, generator=torch.Generator().manual_seed(9))
        d = depth.clone()
        mv = torch.zeros(2, H, W)
        x0 = 4 + 2 * n  # a near block moving 2 px per frame
        color[:, 8:12, x0:x0 + 4] = 0.9
        d[0, 8:12, x0:x0 + 4] = 1.0
        mv[0, 8:12, x0:x0 + 4] = -2.0
        frames.append(Frame(number=n, color=color, depth=d, mv=mv, camera=cam_at(0.5)))
    got = {}
    for backend in ("torch", "numba"):
        stages = pl.load("gffe-extrap").build("extrap")
        state = RunState()
        for i, f1 in enumerate(frames):
            ctx = make_ctx(frames[i - 1] if i else None, f1, 0.5, "extrap")
            ctx.update(state=state, prev_time=0.0, backend=backend)
            out = pl.run_stages(stages, ctx)
        got[backend] = out
        far = torch.ones(H, W, dtype=torch.bool)
        far[5:15, :] = False  # the block's rows, its rim and its contact with the background
        assert (out["mv"][:, far] == 0).all()
        assert torch.equal(out["color"][:, far], frames[-1].color[:, far])
    for k in ("color", "depth", "mv"):  # (the pipelines' contract: tests/test_kernels.py)
        check(k, got["numba"][k], got["torch"][k], PIPELINE)


def test_nearest_depth_wins_in_the_warp():
    cam = cam_at(0.0)
    d = torch.full((1, H, W), D)
    d[0, :, 10:14] = 2.0  # a near pillar
    X = unproject(d, cam)
    color = torch.zeros(3, H, W)
    color[0, :, 10:14] = 1.0
    # move every far pixel 3 px right, onto the pillar: the pillar must stay on top
    px, py, _, _ = project(X, cam, (H, W))
    moved = X.clone()
    far = d[0] > 5
    shift = unproject(d, cam, px + 3.0, py)
    moved[:, far] = shift[:, far]
    out = warp_positions(color, moved, (cam.world_to_camera, cam.projection), "nearest")
    assert (out["color"][0, :, 10:14] == 1.0).all()
    assert torch.allclose(out["depth"][0, :, 10:14], torch.full((H, 4), 2.0), rtol=1e-5)


# -------------------------------------------------------------------------- background

def test_background_behind_a_moving_object_is_collected_and_projected():
    cam = cam_at(0.0)
    bgc = torch.rand(3, H, W, generator=torch.Generator().manual_seed(5))
    d_wall = torch.full((1, H, W), D)
    # frame 0: object over columns 4..9; frame 1: it moved to 12..17 (wall behind 4..9 seen)
    c0, d0 = bgc.clone(), d_wall.clone()
    c0[:, :, 4:10], d0[0, :, 4:10] = 1.0, 3.0
    c1, d1 = bgc.clone(), d_wall.clone()
    c1[:, :, 12:18], d1[0, :, 12:18] = 1.0, 3.0
    static0 = torch.ones(1, H, W, dtype=torch.bool)
    static0[0, :, 4:10] = False
    layers = collect_background(c0, d0, static0, cam)
    static1 = torch.ones(1, H, W, dtype=torch.bool)
    static1[0, :, 12:18] = False
    layers = collect_background(c1, d1, static1, cam, layers, cam)
    assert layers[0]["valid"].all()  # the wall behind the object at 12..17 came from frame 0
    assert torch.equal(layers[0]["color"][:, :, 12:18], bgc[:, :, 12:18])
    holes = torch.zeros(1, H, W, dtype=torch.bool)
    holes[0, :, 12:15] = True
    c, d, m, filled = project_background(layers, cam, cam, holes)
    assert torch.equal(filled, holes)
    assert torch.equal(c[:, :, 12:15], bgc[:, :, 12:15])
    assert (m.abs() < 1e-3).all()


@pytest.mark.parametrize("scale", [1, 2])
def test_layer_1_keeps_the_background_behind_a_static_occluder(scale):
    """The wall seen in frame 0 goes to layer 1 once a static object covers it in frame 1
    (Case 2). At full size (layer1_scale=1, the default) a hole there gets the wall's own
    pixels back; the paper's quarter-size layer gives one fragment per 2x2 cell."""
    cam = cam_at(0.0)
    bgc = torch.rand(3, H, W, generator=torch.Generator().manual_seed(8))
    d_wall = torch.full((1, H, W), D)
    c1, d1 = bgc.clone(), d_wall.clone()
    c1[:, :, 12:18], d1[0, :, 12:18] = 1.0, 3.0
    static = torch.ones(1, H, W, dtype=torch.bool)
    layers = collect_background(bgc, d_wall, static, cam, layer1_scale=scale)
    layers = collect_background(c1, d1, static, cam, layers, cam, layer1_scale=scale)
    assert tuple(layers[1]["depth"].shape[-2:]) == ((H, W) if scale == 1 else (H // 2, W // 2))
    # columns 13..16: the silhouette columns 12 and 17 have wall beside them (not deeper
    # than their whole 3x3 neighbourhood: rounding, not occlusion) and stay out
    if scale == 1:
        assert layers[1]["valid"][0, :, 13:17].all() and layers[1]["valid"].sum() == H * 4
    # the occluder (layer 0) moved away in the extrapolated view: only layer 1 is left there
    layers[0]["valid"][:, :, 12:18] = False
    layers[0]["depth"][:, :, 12:18] = math.inf
    holes = torch.zeros(1, H, W, dtype=torch.bool)
    holes[0, :, 13:17] = True
    for filt in ("nearest", "bilinear"):
        c, d, _, filled = project_background(layers, cam, cam, holes, filt)
        assert torch.equal(filled, holes)
        assert torch.allclose(d[0, :, 13:17], torch.full((H, 4), D))
        if scale == 1:
            assert float((c[:, :, 13:17] - bgc[:, :, 13:17]).abs().max()) < 1e-3, filt
        else:
            assert not torch.allclose(c[:, :, 13:17], bgc[:, :, 13:17], atol=1e-2)


def test_bilinear_background_projection_reads_the_layer_at_the_sub_pixel_place():
    """A camera move of 0.3 px at the wall's depth: filter=bilinear reads the layer between
    two cells (the backward warp of the texture); nearest takes one cell."""
    from fgcli.ops.warp import backward_warp

    cam0 = cam_at(0.0)
    dx = 2 * D * 0.3 / (proj()[0, 0] * W)  # the wall moves 0.3 px left
    bgc = torch.rand(3, H, W, generator=torch.Generator().manual_seed(9))
    d_wall = torch.full((1, H, W), D)
    layers = collect_background(bgc, d_wall, torch.ones(1, H, W, dtype=torch.bool), cam0)
    holes = torch.ones(1, H, W, dtype=torch.bool)
    want, _ = backward_warp(bgc, torch.stack([torch.full((H, W), 0.3), torch.zeros(H, W)]))
    cb, _, _, fb = project_background(layers, cam0, cam_at(dx), holes, "bilinear")
    cn, _, _, fn = project_background(layers, cam0, cam_at(dx), holes, "nearest")
    inner = (slice(None), slice(None), slice(1, W - 2))
    assert fb[0][:, 1:W - 2].all() and fn[0][:, 1:W - 2].all()
    assert torch.allclose(cb[inner], want[inner], atol=1e-3)
    assert float((cn[inner] - want[inner]).abs().max()) > 0.05


def test_a_surface_entering_across_the_border_hides_the_older_background():
    """bg_project.entering: a hole whose frame-1 surface came in across the right border
    (its vector leads off-screen) and is nearer than the layers' fragment takes frame 1 at
    the pixel; a hole whose vector stays on screen keeps the layers' fragment, unless
    (emerging) a nearer surface stands where the vector leads."""
    from fgcli.ops.gffe import entering_surface

    filled = torch.zeros(1, H, W, dtype=torch.bool)
    filled[0, :, W - 4:] = True
    filled[0, :, 4:8] = True
    depth = torch.full((1, H, W), D)
    c1 = torch.rand(3, H, W, generator=torch.Generator().manual_seed(4))
    d1 = torch.full((1, H, W), 2.0)
    mv1 = torch.zeros(2, H, W)
    mv1[0] = 10.0  # everything moves left: it was 10 px to the right
    _, _, take = entering_surface(filled, depth, c1, d1, mv1, 0.5)
    assert take[0, :, W - 4:].all() and not take[0, :, :W - 4].any()
    d1[0, :, W - 4:] = 2 * D  # farther than the layers' fragment: the layers keep it
    _, _, take = entering_surface(filled, depth, c1, d1, mv1, 0.5)
    assert not take.any()
    # behind: columns 4..7 read x + 5 = 9..12, where a nearer surface stands in frame 1:
    # their surface came out from behind it
    d1[0, :, 9:13] = 1.0
    _, _, take = entering_surface(filled, depth, c1, d1, mv1, 0.5)
    assert not take.any()
    _, _, take = entering_surface(filled, depth, c1, d1, mv1, 0.5, behind=True)
    assert take[0, :, 4:8].all() and int(take.sum()) == H * 4


def test_subset_and_dense_paths_agree(monkeypatch):
    """The depth-matched lookup and the bilinear layer reading compute only the pixels they
    need on the CPU; the dense path (what CUDA runs, no read-back) gives the same result."""
    import fgcli.ops.gffe as G

    g = torch.Generator().manual_seed(11)
    cam0, cam1 = cam_at(0.0), cam_at(0.05)
    d0 = 5 + 10 * torch.rand(1, H, W, generator=g)
    d1 = 5 + 10 * torch.rand(1, H, W, generator=g)
    mv = 3 * torch.randn(2, H, W, generator=g)
    layers = collect_background(torch.rand(3, H, W, generator=g), d0,
                                torch.rand(1, H, W, generator=g) > 0.2, cam0, layer1_scale=1)
    holes = torch.rand(1, H, W, generator=g) > 0.5

    def both():
        traj, dyn = track_history(d1, mv, cam1, cam0, d0, k=2)
        return (traj, dyn) + project_background(layers, cam0, cam1, holes, "bilinear")

    sub = both()
    monkeypatch.setattr(G, "reads_back", lambda t: False)
    dense = both()
    for a, b in zip(sub, dense):
        assert torch.equal(a, b)


def test_push_pull_fills_every_hole_finitely():
    color = torch.rand(3, 7, 5)
    valid = torch.zeros(1, 7, 5, dtype=torch.bool)
    valid[0, 0, 0] = True
    depth = torch.full((1, 7, 5), math.inf)
    depth[0, 0, 0] = 4.0
    c, d = push_pull_fill(color, valid, depth)
    assert torch.isfinite(c).all() and torch.allclose(c, color[:, :1, :1].expand(3, 7, 5))
    assert torch.allclose(d, torch.full((1, 7, 5), 4.0))
    c, d = push_pull_fill(color, torch.zeros_like(valid), depth)  # nothing valid
    assert torch.isfinite(c).all() and not torch.isnan(d).any()
    c, _ = push_pull_fill(torch.rand(3, 1, 1), torch.zeros(1, 1, 1, dtype=torch.bool))
    assert torch.isfinite(c).all()


# ---------------------------------------------------------------- pipeline, hard cases

def _run_pipe(frames, alpha=0.5, state=None, detect_cuts=False, name="gffe-extrap"):
    stages = pl.load(name).build("extrap")
    state = state or RunState()
    outs = []
    for i, f1 in enumerate(frames):
        ctx = make_ctx(frames[i - 1] if i else None, f1, alpha, "extrap")
        ctx["state"], ctx["prev_time"] = state, 0.0
        outs.append(pl.run_stages(stages, ctx, detect_cuts=detect_cuts))
    return outs, state


def test_first_frame_and_sky_give_finite_output():
    g = torch.Generator().manual_seed(1)
    frames = []
    for n in range(3):
        depth = 1 + 5 * torch.rand(1, H, W, generator=g)
        depth[0, :8] = math.inf  # sky rows
        depth[0, 10, :4] = 0.0
        depth[0, 11, :4] = float("nan")
        mv = (torch.rand(2, H, W, generator=g) - 0.5) * 6
        mv[:, 12, 0] = float("nan")
        frames.append(Frame(number=n, color=torch.rand(3, H, W, generator=g), depth=depth,
                            mv=mv, camera=cam_at(0.2 * n)))
    outs, state = _run_pipe(frames)
    for o in outs:
        assert torch.isfinite(o["color"]).all() and torch.isfinite(o["mv"]).all()
        assert not torch.isnan(o["depth"]).any()
        # sky stays sky (a few random-motion fragments may land on it)
        assert torch.isinf(o["depth"][0, :6, 6:W - 6]).float().mean() > 0.9
    traj = state.store["gffe"]["traj"]
    assert traj is not None and torch.isfinite(traj).all()
    assert (traj[:, 3, :8] == 0).all()  # sky: directions, never NaN positions


def test_without_cameras_the_pipeline_refuses_clearly():
    f = Frame(number=0, color=torch.rand(3, 4, 4), depth=torch.ones(1, 4, 4),
              mv=torch.zeros(2, 4, 4))
    with pytest.raises(InputError, match="needs per-frame cameras"):
        _run_pipe([f])


def test_a_scene_cut_resets_the_history():
    g = torch.Generator().manual_seed(2)
    mk = lambda n, c: Frame(number=n, color=c, depth=torch.full((1, H, W), D),  # noqa: E731
                            mv=torch.zeros(2, H, W), camera=cam_at(0.1 * n))
    bright = torch.rand(3, H, W, generator=g) * 0.2 + 0.8
    dark = torch.rand(3, H, W, generator=g) * 0.05
    frames = [mk(0, bright), mk(1, bright.roll(1, -1)), mk(2, dark)]
    stages = pl.load("gffe-extrap").build("extrap")
    state = RunState()
    for i, f1 in enumerate(frames):
        ctx = make_ctx(frames[i - 1] if i else None, f1, 0.5, "extrap")
        ctx["state"], ctx["prev_time"] = state, 0.0
        before = dict(state.store.get("gffe", {}))
        ctx = pl.run_stages(stages, ctx, detect_cuts=True)
        if i == 1:
            assert state.store["gffe"]["bg_frame"] == 1
        if i == 2:
            assert before and ctx["facts"]["scene_cut"]
            assert "gffe" not in state.store  # cleared: the next shot starts empty
            assert torch.equal(ctx["color"], dark)


def test_no_work_on_a_static_frame_stages_are_skipped():
    f = plane_frame(0, 0.0, torch.rand(3, H, W))
    stages = pl.load("gffe-extrap").build("extrap")
    tm = pl.Timings()
    state = RunState()
    for n in range(3):
        ctx = make_ctx(f.replace(number=n - 1) if n else None, f.replace(number=n), 0.5,
                       "extrap")
        ctx["state"], ctx["prev_time"] = state, 0.0
        ctx = pl.run_stages(stages, ctx, tm, detect_cuts=False)
        assert torch.equal(ctx["color"], f.color)
    skipped = {s for _, s, _ in tm.skipped}
    assert {"history", "warp", "bg_project", "hole_fill", "position"} <= skipped
    # the layers are collected once and kept while nothing moves
    kept = [n for n, s, w in tm.skipped if s == "background" and "kept" in w]
    assert len(kept) == 2 and state.store["gffe"]["bg"] is not None


def test_count_three_reuses_the_per_frame_state():
    dx = 0.1
    frames = [plane_frame(n, dx * n, torch.rand(3, H, W), mv_x=shift_per_frame(dx))
              for n in range(2)]
    stages = pl.load("gffe-extrap").build("extrap")
    state = RunState()
    tm = pl.Timings()
    for i, f1 in enumerate(frames):
        for a in (0.25, 0.5, 0.75):
            ctx = make_ctx(frames[i - 1] if i else None, f1, a, "extrap")
            ctx["state"], ctx["prev_time"] = state, 0.0
            pl.run_stages(stages, ctx, tm, detect_cuts=False)
    why = [w for _, s, w in tm.skipped if s == "history"]
    assert why.count("tracked once per rendered frame") == 4


# ------------------------------------------------------------------------ runs, chunks

def _cli(args):
    r = CliRunner().invoke(cli, args)
    assert r.exit_code == 0, r.output
    return r


def test_chunked_run_is_byte_identical_to_one_run(tmp_path):
    import filecmp
    import json

    base = ["extrapolate", ORBIT, None, "--pipeline", "gffe-extrap", "--alpha", "0.5",
            "--frames", "0-8x2", "--no-progress"]
    one = tmp_path / "one"
    _cli([x if x is not None else str(one) for x in base])
    ch = tmp_path / "chunks"
    for k in (1, 2, 3):
        _cli([x if x is not None else str(ch) for x in base] + ["--chunk", f"{k}/3"])
    names = sorted(f for f in os.listdir(one) if f.endswith(".exr"))
    assert len(names) == 5
    assert names == sorted(f for f in os.listdir(ch) if f.endswith(".exr"))
    for n in names:
        assert filecmp.cmp(one / n, ch / n, shallow=False), n
    run = json.loads((one / "fgen-run.json").read_text())
    assert set(run["render_windows"]) == {"0", "2", "4", "6", "8"}
    assert all(len(w) == 4 and w[0] <= -1 and w[2] >= 1 for w in run["render_windows"].values())
    c2 = json.loads((ch / "fgen-run.chunk-2-of-3.json").read_text())
    assert c2["replayed_for_history"] >= 1  # job 0 replayed for chunk 2 of 3


def test_count_three_makes_three_frames_per_rendered_frame(tmp_path):
    out = tmp_path / "o"
    _cli(["extrapolate", ORBIT, str(out), "--pipeline", "gffe-extrap", "--alpha", "0.25",
          "--count", "3", "--frames", "0-2x2", "--no-progress"])
    assert len([f for f in os.listdir(out) if f.endswith(".exr")]) == 6
    shutil.rmtree(out)


def test_rigid_camera_model_is_exact_on_an_orbit_and_linear_is_not():
    import math as _m

    def orbit(deg):
        a = _m.radians(deg)
        pos = np.array([7 * _m.sin(a), 1.5, 7 * _m.cos(a)])
        return look_at(pos, -pos + np.array([0, 0.5, 0]), [0, 1, 0])

    p = np.eye(4)
    v0, v1, v2 = orbit(0.0), orbit(8.0), orbit(12.0)
    vr, _ = extrapolate_camera((v0, p), (v1, p), 0.5, model="rigid")
    vl, _ = extrapolate_camera((v0, p), (v1, p), 0.5, model="linear")
    assert np.allclose(vr, v2, atol=1e-9)
    assert not np.allclose(vl, v2, atol=1e-4)
    # pure translation: both models agree (Eq. 2 is exact there)
    t0, t1 = look_at([0, 0, 5], [0, 0, -1], [0, 1, 0]), look_at([1, 0, 5], [0, 0, -1], [0, 1, 0])
    a, _ = extrapolate_camera((t0, p), (t1, p), 0.5, model="rigid")
    b, _ = extrapolate_camera((t0, p), (t1, p), 0.5, model="linear")
    assert np.allclose(a, b, atol=1e-9)
    with pytest.raises(ValueError):
        extrapolate_camera((t0, p), (t1, p), 0.5, model="cubic")


def test_reproject_fill_clamps_off_screen_points_to_the_edge():
    from fgcli.ops.gffe import reproject_fill

    H, W = 8, 16
    p = np.array([[1.0, 0, 0, 0], [0, 2.0, 0, 0], [0, 0, -1.0001, -0.10001], [0, 0, -1.0, 0]])
    v1 = look_at([0, 0, 0], [0, 0, -1], [0, 1, 0])
    vx = look_at([-0.5, 0, 0], [0, 0, -1], [0, 1, 0])  # moved left: new content on the left
    color1 = torch.rand(3, H, W)
    depth1 = torch.full((1, H, W), 5.0)
    valid = torch.ones(1, H, W, dtype=torch.bool)
    valid[..., :2] = False
    depth = torch.full((1, H, W), 5.0)
    c, flow, took = reproject_fill(torch.zeros(3, H, W), valid, depth, color1, depth1,
                                   (v1, p), (vx, p), offscreen="clamp")
    assert bool(took[0, :, 0].all())
    assert torch.allclose(c[:, :, 0], color1[:, :, 0], atol=1e-5)  # the edge column
    _, _, took2 = reproject_fill(torch.zeros(3, H, W), valid, depth, color1, depth1,
                                 (v1, p), (vx, p), offscreen="skip")
    assert not bool(took2[0, :, 0].any())


def test_first_frame_moving_pixels_stay_out_of_the_background():
    H, W = 8, 8
    p = np.array([[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, -1.0001, -0.10001], [0, 0, -1.0, 0]])
    cam = (look_at([0, 0, 0], [0, 0, -1], [0, 1, 0]), p)
    depth = torch.full((1, H, W), 5.0)
    mv = torch.zeros(2, H, W)
    mv[0, 2:4, 2:4] = 3.0
    _, dyn = track_history(depth, mv, cam, None, None, None, 3, 0.5, "mv")
    assert bool(dyn[0, 2:4, 2:4].all()) and int(dyn.sum()) == 4
    bg = collect_background(torch.rand(3, H, W), depth, ~dyn, cam)
    assert not bool(bg[0]["valid"][0, 2:4, 2:4].any())


def test_edge_guard_marks_silhouettes_not_slanted_floors():
    from fgcli.ops.gffe import _edge_pixels

    ramp = (5.0 + 0.5 * torch.arange(8.0))[None, :, None].expand(1, 8, 8).contiguous()
    none = torch.zeros(1, 8, 8, dtype=torch.bool)
    assert not bool(_edge_pixels(ramp, none, 0.02).any())  # 10 % per row, but planar
    step = torch.full((1, 8, 8), 10.0)
    step[..., :4] = 2.0
    e = _edge_pixels(step, none, 0.02)
    assert bool(e[0, :, 4].all()) and not bool(e[0, :, 3].any()) and not bool(e[0, :, 6].any())


@pytest.fixture(scope="module")
def overscan_seq(tmp_path_factory):
    """The bundled orbit_overscan scene (24 px overscan border), 6 frames at 256x144, 2x2
    samples per pixel (the scene's 4x4 costs twice the time and changes no conclusion)."""
    d = tmp_path_factory.mktemp("ovs")
    r = CliRunner().invoke(cli, ["synth", os.path.join(ROOT, "sample_data", "scenes",
                                                       "orbit_overscan.toml"),
                                 str(d / "input"), "--gt", str(d / "gt"), "--frames", "6",
                                 "--spp", "2", "--no-progress"])
    assert r.exit_code == 0, r.output
    return d


def test_overscan_border_is_read_beside_the_display_window(overscan_seq):
    from fgcli.io.options import open_input

    f = open_input(str(overscan_seq / "input")).read(2)
    o = f.overscan
    assert o is not None and o["origin"][0] < 0 and o["origin"][1] < 0
    x, y = -o["origin"][0], -o["origin"][1]
    assert o["color"].shape[-2:] == (144 + 2 * y, 256 + 2 * x) == o["depth"].shape[-2:]
    # the display window is the middle of the rendered region, the same values
    assert torch.equal(o["color"][:, y:y + 144, x:x + 256], f.color)
    assert torch.equal(o["depth"][:, y:y + 144, x:x + 256], f.depth)
    assert f.color.shape[-2:] == (144, 256)
    g = f.to("cpu")
    assert g.overscan["origin"] == o["origin"]


def test_window_fills_out_of_screen_holes_from_the_overscan_border(overscan_seq, tmp_path):
    """gffe-extrap's window ablation: with the rendered border the out-of-screen
    disocclusions of an orbiting camera are filled from pixels the renderer drew (the
    border's fragments splatted, then the reprojection reading it); without it (window=off)
    from frame 1's edge pixel. The border must score better overall and on disoccluded
    pixels (here +0.08 / +0.25 dB; docs/results.md, 17 frames at 4x4 spp: +0.34 / +1.03;
    deterministic renders, float differences between CPUs are ~1e-3 dB)."""
    import json

    js = tmp_path / "e.json"
    r = CliRunner().invoke(cli, ["eval", str(overscan_seq), "--pipeline",
                                 "gffe-extrap,gffe-extrap:window=off", "--mode", "extrap",
                                 "--json", str(js), "--no-progress", "--no-hdr-flip"])
    assert r.exit_code == 0, r.output
    res = json.loads(js.read_text())["pipelines"]
    on, off = res["gffe-extrap"], res["gffe-extrap:window=off"]
    assert on["psnr"] > off["psnr"] + 0.03
    assert on["psnr_disoccluded"] > off["psnr_disoccluded"] + 0.1


def test_a_data_window_shifted_off_the_display_window_is_no_border(tmp_path, overscan_seq):
    """Only a data window that contains the whole display window is an overscan border; one
    reaching out on one side and short of it on another is read as before (padded)."""
    from fgcli.io import exr, layouts
    from fgcli.io.options import open_input

    f = open_input(str(overscan_seq / "input")).read(2)
    chans, types = layouts.encode(f.replace(overscan=None), "fgen")
    h, w = f.height, f.width
    for name, win, border in (("shifted", (-4, 2), False), ("around", (-4, -4), True)):
        ww, hh = (w + 8, h + 8) if border else (w + 4, h - 2)
        x0, y0 = win

        def grown(a):  # the display pixels placed in a (hh, ww) window at (x0, y0)
            out = np.zeros((hh, ww), a.dtype)
            ys, xs = slice(max(0, -y0), min(hh, h - y0)), slice(max(0, -x0), min(ww, w - x0))
            out[ys, xs] = a[ys.start + y0:ys.stop + y0, xs.start + x0:xs.stop + x0]
            return out

        d = tmp_path / name
        d.mkdir()
        exr.write_exr(str(d / "s.0001.exr"), {k: grown(v) for k, v in chans.items()}, types,
                      {}, "zip", data_window=(x0, y0, ww, hh), display=(w, h))
        g = open_input(str(d)).read(1)
        assert (g.overscan is not None) == border, name
        assert g.color.shape[-2:] == (h, w)


def test_vector_rule_fills_a_hole_from_behind_the_object_that_left_it():
    """Mob-FGSR's extrapolation rule on gffe's holes: an object moving right leaves a hole
    at its trailing edge; the hole reads frame 1 behind the object along its vector (the
    background texture with today's shading). A hole whose vector leads onto something
    nearer, or that has no vector, is left to the next fill."""
    from fgcli.ops.gffe import vector_rule_fill

    H, W = 6, 12
    x = torch.arange(W, dtype=torch.float32).view(1, 1, W).expand(1, H, W)
    color1 = torch.cat([x / 10, x / 20, torch.ones(1, H, W)])  # a horizontal ramp
    depth1 = torch.full((1, H, W), 10.0)
    depth1[..., 6:9] = 2.0  # the object, columns 6-8 in frame 1
    depth1[..., 1] = 1.0    # something nearer at column 1
    mv1 = torch.zeros(2, H, W)
    mv1[0, :, 6:9] = -4.0  # the object moved 4 px right since frame 0 (prev = xy + mv)
    mv1[0, :, 3] = -4.0    # column 3's vector leads onto column 1 (nearer)
    valid = torch.ones(1, H, W, dtype=torch.bool)
    for col in (6, 3, 10):  # trailing edge; vector onto a nearer surface; no vector
        valid[..., col] = False
    color, depth, mv = torch.zeros(3, H, W), torch.full((1, H, W), 5.0), torch.zeros(2, H, W)
    c, d, m, took = vector_rule_fill(color, valid, depth, mv, color1, depth1, mv1, 0.5)
    assert took[0, :, 6].all() and int(took.sum()) == H  # only the trailing edge
    assert torch.equal(c[:, :, 6], color1[:, :, 4])  # read at 6 + 0.5 * -4 = 4
    assert (d[0, :, 6] == 10.0).all() and (m[0, :, 6] == -2.0).all() and (m[1] == 0).all()
    for col in (3, 10):  # untouched for the next fill
        assert (c[:, :, col] == 0).all() and (d[0, :, col] == 5.0).all()
        assert (m[:, :, col] == 0).all()
    assert torch.equal(c[:, :, 0], color[:, :, 0])  # valid pixels untouched
