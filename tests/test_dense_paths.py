"""The GPU paths of the torch ops, run on the CPU (issue 9 item 6).

On CUDA every value an op reads back to Python (`.item()`, `bool(t.any())`, `nonzero`) is a
host round-trip that stalls the stream, so there the ops take dense, branch-free paths
(`fgcli.ops._util.reads_back`). `FORCE_DENSE` makes the CPU take them too, so this machine
tests them: they must give what the CPU paths give, on random inputs and on the hard cases
of docs/design.md section 5, and the stages of the heuristic pipelines must read nothing back
(a trap on every read-back method stands in for torch's CUDA sync debug mode, which
`benchmarks/stages.py --device cuda --sync-report` uses on a GPU).
"""
from __future__ import annotations

import contextlib

import pytest
import torch

from fgcli import ops as R
from fgcli.ops import _util

from test_kernels import CASES, IDS, _splats, dense

INF, NAN = float("inf"), float("nan")


def both(fn):
    """fn() on the CPU paths and on the dense paths."""
    a = fn()
    with dense():
        b = fn()
    return a, b


def close(name, a, b, exact=True):
    """Equal (NaN == NaN); exact=False: within float32 rounding of a sum of 8 terms."""
    if isinstance(a, R.SplatResult):
        for f in ("to1", "to0", "depth", "valid", "source", "filled", "holes"):
            close(f"{name}.{f}", getattr(a, f), getattr(b, f), exact)
        return
    if isinstance(a, tuple):
        for i, (x, y) in enumerate(zip(a, b)):
            close(f"{name}[{i}]", x, y, exact)
        return
    assert a.shape == b.shape and a.dtype == b.dtype, name
    if not a.dtype.is_floating_point:
        assert torch.equal(a, b), name
        return
    eq = (a == b) | (a.isnan() & b.isnan())
    if not exact:
        eq |= torch.isclose(a, b, rtol=1e-6, atol=1e-6)
    assert bool(eq.all()), f"{name}: {int((~eq).sum())} of {eq.numel()} differ"


@pytest.mark.parametrize("name,f", CASES, ids=IDS)
def test_sanitisers_and_warps(name, f):
    for key in ("c0", "c1", "mv1", "d1", "d0"):
        close(f"sanitize_values {key}", *both(lambda: R.sanitize_values(f[key])))
    close("sanitize_mv", *both(lambda: R.sanitize_mv(f["mv1"])))
    close("sanitize_depth", *both(lambda: R.sanitize_depth(f["d1"])))
    close("sanitize_depth 0", *both(lambda: R.sanitize_depth(f["d0"])))
    for mode in ("bilinear", "nearest", "catmull-rom"):
        close(f"warp {mode}", *both(lambda: R.backward_warp(f["c0"], f["mv1"], mode)))
    close("sample_nearest", *both(lambda: R.sample_nearest(f["d1"], f["mv1"])))


@pytest.mark.parametrize("name,f", CASES, ids=IDS)
def test_gap_fill_and_extrap_fill(name, f):
    for label, dd, mm, mv0, a, kw, d0 in _splats(f):
        r = R.splat_motion(dd, mm, mv0, a, depth0=d0, **kw)
        for thr in (0.01, 0.0, 1.0):
            close(f"{label} gap_fill {thr}", *both(lambda: R.gap_fill(r, thr)))
            close(f"{label} gap_fill mean {thr}", *both(lambda: R.gap_fill(r, thr, "mean")),
                  exact=False)
        close(f"{label} fallback", *both(
            lambda: R.gap_fill(r, 0.01, "nearest", f["mv0"], f["d0"])))
        close(f"{label} fallback mv", *both(lambda: R.gap_fill(r, 0.01, "nearest", f["mv1"])))
        if r.mode == "extrap":
            g = R.gap_fill(r)
            for thr in (1e-3, 0.5):
                close(f"{label} extrap_fill {thr}", *both(
                    lambda: R.fill_extrap_holes(g, f["mv1"], dd, thr)))


def test_gap_fill_dense_batched():
    f = CASES[0][1]
    dd, mm = R.dilate_nearest_depth(f["d1"], f["mv1"])
    r = R.splat_motion(dd[None].expand(2, -1, -1, -1), mm[None].expand(2, -1, -1, -1),
                       f["mv0"][None].expand(2, -1, -1, -1), 0.4)
    close("batched", *both(lambda: R.gap_fill(r, 0.01)))


PIPES = [("mob-fgsr", "interp"), ("mob-fgsr", "extrap"), ("mv-warp", "interp"),
         ("mv-warp", "extrap"), ("blend", "interp"), ("repeat", "interp")]


def _scene_frames(tiny_scene):
    s0, s1 = tiny_scene(0), tiny_scene(1)
    return {f"{k}{i}": torch.from_numpy(s[key]) for i, s in ((0, s0), (1, s1))
            for k, key in (("c", "color"), ("d", "depth"), ("mv", "mv"))}


@pytest.fixture(scope="module")
def rendered():
    """Three frames of the bundled blade scene at 64x40 with cameras (gffe needs them)."""
    import os

    from fgcli.synth import load_scene, render

    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    scene = load_scene(os.path.join(root, "sample_data", "scenes", "blade.toml"), size=(64, 40))
    return [render(scene, 2.0 + i, 1.0 + i, spp=1) for i in range(3)]


def _run(name, mode, frames, alpha, trap=False):
    """Run a pipeline over consecutive frame pairs (recurrent state carried), with the
    per-frame facts computed first; trap: the stages must read nothing back."""
    from fgcli import pipeline as pl
    from fgcli.pipeline import frame_facts, run_stages
    from fgcli.runner import RunState, make_ctx

    stages = pl.load(name).build(mode)
    state = RunState()
    outs = []
    with torch.inference_mode():
        for f0, f1 in zip(frames, frames[1:]):
            ctx = make_ctx(f0, f1, alpha, mode)
            ctx.update(prev_time=0.0, state=state, backend="torch")
            facts = frame_facts(ctx)
            with trap_read_back() if trap else contextlib.nullcontext():
                out = run_stages(stages, ctx, None, facts=facts)
            outs.append(tuple(out[k] for k in ("color", "depth", "mv")))
    return outs


@pytest.mark.parametrize("name,mode", PIPES + [("gffe-extrap", "extrap"),
                                               ("fsr3-interp", "interp"),
                                               ("fsr3-interp:optical_flow=off", "interp")])
def test_pipelines_dense_equal_cpu_paths(name, mode, rendered):
    for alpha in ((0.3, 0.5) if mode == "interp" else (0.5, 1.0)):
        a, b = both(lambda: _run(name, mode, rendered, alpha))
        for i, (x, y) in enumerate(zip(a, b)):
            close(f"{name} {mode} {alpha} frame {i}", x, y, exact=not name.startswith("fsr3"))


class ReadBack(AssertionError):
    pass


@contextlib.contextmanager
def trap_read_back():
    """Every way a tensor value reaches Python raises ReadBack (as a CUDA sync would)."""
    names = ("item", "tolist", "numpy", "__bool__", "__float__", "__int__", "__index__",
             "nonzero", "any", "all")
    saved = {n: getattr(torch.Tensor, n) for n in names}

    def make(n):
        orig = saved[n]

        def f(self, *a, **k):
            if n in ("any", "all"):  # the reductions are fine; bool() of them is not
                return orig(self, *a, **k)
            raise ReadBack(f"Tensor.{n} called on a {tuple(self.shape)} tensor")
        return f

    for n in names:
        setattr(torch.Tensor, n, make(n))
    saved_nz, saved_tensor = torch.nonzero, torch.tensor
    torch.nonzero = lambda *a, **k: (_ for _ in ()).throw(ReadBack("torch.nonzero"))

    def tensor(data, *a, **k):  # a tensor from host data is a blocking copy to a GPU
        raise ReadBack(f"torch.tensor({data!r:.40})")

    torch.tensor = tensor
    try:
        yield
    finally:
        for n, v in saved.items():
            setattr(torch.Tensor, n, v)
        torch.nonzero, torch.tensor = saved_nz, saved_tensor


@pytest.mark.parametrize("name,mode", PIPES + [
    ("fsr3-interp", "interp"),
    # the render window is host metadata (fgen-run.json); with a set plane depth it needs
    # no depth median, and then gffe reads nothing back either
    ("gffe-extrap:window.plane_depth=5", "extrap")])
def test_pipelines_read_nothing_back_on_the_dense_path(name, mode, rendered):
    """No host round-trip inside the stages on the GPU path (the per-frame facts read their
    values back once, before the stages)."""
    with dense():
        outs = _run(name, mode, rendered, 0.5, trap=True)
    assert all(bool(torch.isfinite(c).all()) for c, _, _ in outs)


def test_gffe_with_an_overscan_border_reads_nothing_back(rendered):
    """The border paths of gffe's hole fill (border splat, border reprojection) on the
    dense path: a border made by edge-replicating the frames 6 px (the values do not
    matter here, the read-backs do)."""
    import torch.nn.functional as F

    def bordered(f):
        pad = lambda t: F.pad(t[None], (6, 6, 6, 6), mode="replicate")[0]  # noqa: E731
        return f.replace(overscan={"origin": (-6, -6), "color": pad(f.color),
                                   "depth": pad(f.depth)})

    frames = [bordered(f) for f in rendered]
    with dense():
        on = _run("gffe-extrap:window.plane_depth=5", "extrap", frames, 0.5, trap=True)
    off = _run("gffe-extrap:window.plane_depth=5", "extrap", rendered, 0.5)
    assert all(bool(torch.isfinite(c).all()) for c, _, _ in on)
    assert len(on) == len(off)


def test_the_trap_catches_a_read_back():
    for fn in (lambda: bool(torch.zeros(3).any()), lambda: torch.zeros(3).sum().item(),
               lambda: torch.zeros(3).nonzero(), lambda: torch.tensor([1, 2]),
               lambda: float(torch.zeros(()))):
        with pytest.raises(ReadBack):
            with trap_read_back():
                fn()


def test_facts_read_back_once_on_the_dense_path(tiny_scene):
    from fgcli.frame import Frame
    from fgcli.pipeline import frame_facts
    from fgcli.runner import make_ctx

    f = _scene_frames(tiny_scene)
    fr = [Frame(number=n, color=f[f"c{n}"], depth=f[f"d{n}"], mv=f[f"mv{n}"]) for n in (0, 1)]
    ctx = make_ctx(fr[0], fr[1], 0.5, "interp")
    ctx.update(backend="torch")
    host = frame_facts(dict(ctx))
    calls = []
    orig = torch.Tensor.tolist

    def counting(self):
        calls.append(tuple(self.shape))
        return orig(self)

    torch.Tensor.tolist = counting
    try:
        with dense():
            dev = frame_facts(dict(ctx))
    finally:
        torch.Tensor.tolist = orig
    assert len(calls) == 1
    for k in ("any_motion", "history_motion", "scene_cut"):
        assert host[k] == dev[k], k
    assert abs(host["scene_change"] - dev["scene_change"]) < 1e-6
    still = dict(ctx, mv1=torch.zeros_like(ctx["mv1"]), mv0=None)
    with dense():
        assert frame_facts(still)["any_motion"] is False
    nan = dict(ctx, mv1=ctx["mv1"].clone())
    nan["mv1"][0, 0, 0] = NAN
    nan["mv1"] = torch.where(torch.isnan(nan["mv1"]), nan["mv1"], torch.zeros_like(nan["mv1"]))
    with dense():
        assert frame_facts(nan)["any_motion"] is True  # NaN counts as motion


def test_all_set_and_any_set_read_back_as_torch_does():
    g = torch.Generator().manual_seed(3)
    masks = [torch.ones(1, 6, 7, dtype=torch.bool), torch.zeros(1, 6, 7, dtype=torch.bool),
             torch.rand(1, 6, 7, generator=g) > 0.02, torch.rand(1, 6, 7, generator=g) > 0.98,
             (torch.rand(2, 9, 8, generator=g) > 0.5)[:, ::2, 1::3],  # not contiguous
             torch.zeros(0, dtype=torch.bool), torch.rand(1, 4, 4, generator=g)]  # float
    masks[0][0, 5, 6] = False  # the only hole is the last element
    for m in masks:
        assert _util.all_set(m) == bool(m.all()) and _util.any_set(m) == bool(m.any())
