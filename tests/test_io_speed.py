"""The I/O fast paths (issue 9, item 4) give the same values as the plain ones.

read_channels decodes spans of channels (half spans as half) into channel-first float32
blocks; layouts take a field's planes from a block without copying; the runner decodes the
first frames before torch is loaded (read_raw, finished later) and limits thread counts
while its I/O threads run.
"""
from __future__ import annotations

import os
from fractions import Fraction

import numpy as np
import pytest

from fgcli.io import exr, layouts
from fgcli.io.reader import SequenceReader


def _plane(rng, h, w, kind):
    a = (rng.random((h, w), dtype=np.float32) - 0.3) * 50
    return a.astype(np.float16).astype(np.float32) if kind == "half" else a


@pytest.mark.parametrize("comp", ["zip", "none", "piz"])
def test_spans_equal_single_channel_reads(tmp_path, comp):
    """Every subset of channels (gaps, half/float mixes) reads the same values as reading
    each channel alone, as float32 (H, W)."""
    rng = np.random.default_rng(3)
    names = ["R", "G", "B", "A", "Z", "a.x", "b.y", "c.z", "d.w", "mv.x", "mv.y"]
    kinds = {n: ("float" if n in ("Z", "mv.x", "mv.y", "c.z") else "half") for n in names}
    chans = {n: _plane(rng, 20, 36, kinds[n]) for n in names}
    p = str(tmp_path / f"s.{comp}.exr")
    exr.write_exr(p, chans, kinds, compression=comp)
    h = exr.read_header(p)
    alone = {n: exr.read_channels(p, [(0, n)], h)[(0, n)] for n in names}
    for n in names:
        assert np.array_equal(alone[n], chans[n])
    subsets = [["R", "G", "B", "A", "Z", "mv.x", "mv.y"], ["Z", "R"], ["mv.y", "R"],
               ["G", "d.w"], names, ["B", "c.z", "mv.x"], ["A"]]
    for sub in subsets:
        got = exr.read_channels(p, [(0, n) for n in sub], h)
        assert set(got) == {(0, n) for n in sub}
        for n in sub:
            g = got[(0, n)]
            assert g.dtype == np.float32 and g.shape == (20, 36)
            assert np.array_equal(g, alone[n]), (sub, n)


def test_spans_merge_small_gaps():
    f = ["half"] * 4 + ["float"] + ["half"] * 7 + ["float"] * 2
    assert exr._spans([0, 1, 2, 3, 4, 12, 13], f) == [(0, 5, "float"), (12, 14, "float")]
    assert exr._spans([0, 1, 2], f) == [(0, 3, "half")]
    assert exr._spans([0, 3], f) == [(0, 4, "half")]  # a gap of 2 is read through
    assert exr._spans([0, 4], f) == [(0, 1, "half"), (4, 5, "float")]
    assert exr._spans([13, 12, 12], f) == [(12, 14, "float")]


def test_planes_view_or_copy():
    block = np.empty((5, 3, 4), np.float32)
    block[:] = np.arange(60, dtype=np.float32).reshape(5, 3, 4)
    v = layouts.planes([block[1], block[2], block[3]])
    assert np.shares_memory(v, block) and np.array_equal(v, block[1:4])
    for arrays, copy in (([block[3], block[2]], False), ([block[1], block[3]], False),
                         ([block[1], block[2]], True)):
        c = layouts.planes(arrays, copy=copy)
        assert not np.shares_memory(c, block)
        assert np.array_equal(c, np.stack(arrays))
    h16 = np.ones((3, 4), np.float16)
    c = layouts.planes([h16, block[0]])
    assert c.dtype == np.float32 and np.array_equal(c[0], np.ones((3, 4)))


@pytest.mark.parametrize("factor", [(1.0, 1.0), (1.0, -1.0), (-1.0, 1.0), (1920.0, 1080.0),
                                    (959.5, 540.0), (0.1, 1 / 3.0), (1e30, 3.0)])
def test_scaled_same_as_float64_path(factor):
    rng = np.random.default_rng(5)
    a = ((rng.random((2, 7, 9), dtype=np.float32) - 0.5) * 1e4).astype(np.float32)
    a[0, 0, 0], a[1, 0, 1] = 3e38, -0.0
    f = np.asarray(factor, np.float64)
    with np.errstate(over="ignore"):
        want = (a * f[:, None, None]).astype(np.float32)
        got = layouts._scaled(a.copy(), f)
    assert got.dtype == np.float32
    assert np.array_equal(got.view(np.uint32), want.view(np.uint32))


def _sequence(tmp_path, tiny_scene, n=4):
    from fgcli.frame import Frame
    from fgcli.io.frames import write_frame

    import torch

    d = tmp_path / "seq"
    d.mkdir()
    for t in range(n):
        s = tiny_scene(t)
        f = Frame(number=t + 1, color=torch.from_numpy(s["color"].astype(np.float32)),
                  depth=torch.from_numpy(s["depth"].astype(np.float32)),
                  mv=torch.from_numpy(s["mv"].astype(np.float32)))
        write_frame(str(d / f"shot.{t + 1:04d}.exr"), f)
    return str(d)


def _same_frame(a, b):
    for k in ("color", "depth", "mv", "alpha", "mv_valid"):
        x, y = getattr(a, k), getattr(b, k)
        assert (x is None) == (y is None), k
        if x is not None:
            assert x.dtype == y.dtype and x.is_contiguous() and torch_equal(x, y), k
    assert a.header == b.header and a.number == b.number


def torch_equal(x, y):
    import torch

    return bool(torch.equal(x, y) or torch.equal(torch.nan_to_num(x), torch.nan_to_num(y)))


def test_read_is_read_raw_then_finish(tmp_path, tiny_scene):
    folder = _sequence(tmp_path, tiny_scene)
    r1 = SequenceReader(folder, fields={"color", "depth", "mv"})
    r2 = SequenceReader(folder, fields={"color", "depth", "mv"})
    for n in r1.numbers:
        _same_frame(r1.read(n), r2.finish(r2.read_raw(n)))
        assert not r1.finish_reads(n)


def test_frame_cache_before_torch_is_loaded(tmp_path, tiny_scene):
    """Frames decoded before torch is loaded come back as RawFrames and are finished by
    get(): the same frames as reader.read()."""
    from fgcli.pipeline import Timings
    from fgcli.runner import FrameCache

    folder = _sequence(tmp_path, tiny_scene)
    ref = SequenceReader(folder, fields={"color", "depth", "mv"})
    r = SequenceReader(folder, fields={"color", "depth", "mv"})
    cache = FrameCache(r, Timings(), keep=8)
    try:
        for n in r.numbers[:2]:
            cache.prefetch(n)
        assert isinstance(cache.frames[r.numbers[0]].result(), layouts.RawFrame)
        cache.torch_loaded.set()
        for n in r.numbers:
            _same_frame(cache.get(n), ref.read(n))
        assert all(not isinstance(f.result(), layouts.RawFrame) for f in cache.frames.values())
    finally:
        cache.close()


def test_first_reads_and_read_ahead(tmp_path):
    from fgcli.runner import first_reads, plan_outputs, read_ahead

    class Out:
        overwrite = False

        def __init__(self, name):
            self.name = name

        def path_for(self, on):
            return str(tmp_path / f"{self.name}.{on}.exr")

    plan = plan_outputs([1, 2, 3, 4, 5], 1, "interp", [Fraction(1, 2)])
    assert first_reads(plan, Out("i"), 4) == [2, 1, 3, 4]
    # outputs already there (resume) are skipped by the guess
    for j in plan["jobs"][:2]:
        open(Out("i").path_for(j[3]), "w").close()
    assert first_reads(plan, Out("i"), 3) == [4, 3, 5]
    extrap = plan_outputs([1, 2, 3], 1, "extrap", [Fraction(1, 2)])
    assert first_reads(extrap, Out("e"), 4) == [1, 2, 3]
    copies = plan_outputs([1, 2, 3], 1, "interp", [Fraction(1, 2)], emit="all")
    assert first_reads(copies, Out("c"), 2) == [1, 2]

    class R:
        def __init__(self, w, h):
            self.width, self.height = w, h

    assert read_ahead(R(1920, 1080)) == 8
    assert read_ahead(R(3840, 2160)) == 4
    assert read_ahead(R(64, 64)) == 16


def test_frame_cache_reads_each_frame_once():
    """With the read-ahead, every frame of a run is decoded once (none evicted early)."""
    from fgcli.pipeline import Timings
    from fgcli.runner import FrameCache, first_reads, plan_outputs

    class R:
        def __init__(self):
            self.reads = []

        def read(self, n):
            self.reads.append(n)
            return n

    class Out:
        overwrite = True

        def path_for(self, on):
            return ""

    for keep in (4, 6, 8):
        for alphas in ([Fraction(1, 2)], [Fraction(1, 4), Fraction(1, 2), Fraction(3, 4)]):
            plan = plan_outputs(list(range(12)), 1, "interp", alphas)
            r = R()
            cache = FrameCache(r, Timings(), keep=keep)
            for n in first_reads(plan, Out(), keep):
                cache.prefetch(n)
            todo = plan["mine"]
            for i, ji in enumerate(todo):
                a, b = plan["jobs"][ji][:2]
                assert cache.get(b) == b and cache.get(a) == a
                for nxt in todo[i + 1:i + 1 + max(1, keep // 2)]:
                    cache.prefetch(plan["jobs"][nxt][1])
                    cache.prefetch(plan["jobs"][nxt][0])
            cache.close()
            assert sorted(r.reads) == list(range(12)), (keep, alphas)


def test_io_threads_restored(monkeypatch):
    import OpenImageIO as oiio
    import torch

    from fgcli.errors import UsageError
    from fgcli.runner import IOThreads

    before = (oiio.get_int_attribute("threads"), oiio.get_int_attribute("exr_threads"),
              torch.get_num_threads())
    monkeypatch.setenv("FGEN_OIIO_THREADS", "1")
    monkeypatch.setenv("FGEN_COMPUTE_THREADS", "1")
    t = IOThreads()
    t.limit_io()
    t.limit_compute("torch", "cpu")
    assert oiio.get_int_attribute("threads") == 1 and torch.get_num_threads() == 1
    t.restore()
    t.restore()  # twice: no effect
    assert (oiio.get_int_attribute("threads"), oiio.get_int_attribute("exr_threads"),
            torch.get_num_threads()) == before
    monkeypatch.setenv("FGEN_OIIO_THREADS", "many")
    with pytest.raises(UsageError, match="FGEN_OIIO_THREADS"):
        IOThreads().limit_io()
    # on a GPU the cores are free for the decoder: OpenImageIO keeps its own setting
    # unless FGEN_OIIO_THREADS asks otherwise
    monkeypatch.delenv("FGEN_OIIO_THREADS")
    t = IOThreads()
    t.limit_io("cuda")
    assert oiio.get_int_attribute("threads") == before[0]
    monkeypatch.setenv("FGEN_OIIO_THREADS", "1")
    t.limit_io("cuda")
    assert oiio.get_int_attribute("threads") == 1
    t.restore()
    assert oiio.get_int_attribute("threads") == before[0]


def test_interpolate_outputs_unchanged_by_thread_settings(tmp_path, tiny_scene, monkeypatch):
    """The thread and read-ahead settings change when work runs, never what is written."""
    from fgcli import pipeline as pl
    from fgcli.io.options import open_output
    from fgcli.runner import run_sequence

    folder = _sequence(tmp_path, tiny_scene, n=5)
    outs = []
    for k, env in enumerate(({}, {"FGEN_OIIO_THREADS": "2", "FGEN_COMPUTE_THREADS": "2",
                                  "FGEN_WRITE_THREADS": "2", "FGEN_READ_AHEAD_MB": "0"})):
        for key, v in env.items():
            monkeypatch.setenv(key, v)
        r = SequenceReader(folder, fields={"color", "depth", "mv"})
        out = open_output(str(tmp_path / f"out{k}"), r)
        run_sequence(r, out, pl.load("mob-fgsr"), "interp", [Fraction(1, 2)],
                     progress=False, backend="torch")
        names = sorted(f for f in os.listdir(out.path) if f.endswith(".exr"))
        assert len(names) == 4
        outs.append({f: open(os.path.join(out.path, f), "rb").read() for f in names})
    assert outs[0] == outs[1]
