"""Low-level EXR access: parts, tiles, data windows, mixed types, metadata, bad files."""
from __future__ import annotations

import os
import stat

import numpy as np
import pytest

from fgcli.errors import InputError, OutputError
from fgcli.io import exr


def planes(h=6, w=8, n=3, seed=0):
    rng = np.random.default_rng(seed)
    return [rng.random((h, w), dtype=np.float32) * 10 for _ in range(n)]


def test_mixed_half_float_scanline(tmp_path):
    r, g, z = planes()
    p = str(tmp_path / "a.exr")
    exr.write_exr(p, {"R": r, "G": g, "Z": z}, {"R": "half", "G": "half", "Z": "float"})
    h = exr.read_header(p)
    part = h.parts[0]
    assert dict(zip(part.channels, part.formats)) == {"R": "half", "G": "half", "Z": "float"}
    assert not part.tiled and part.full_data_window
    got = exr.read_channels(p, [(0, "Z"), (0, "R")], h)
    assert np.array_equal(got[(0, "Z")], z)  # float exact
    assert np.allclose(got[(0, "R")], r, rtol=2 ** -10)  # half
    assert got[(0, "R")].dtype == np.float32


def test_tiled_with_data_window_padded_to_display(tmp_path):
    r, g = planes(4, 5, 2)
    p = str(tmp_path / "t.exr")
    exr.write_exr(p, {"R": r, "G": g}, {"R": "float", "G": "float"}, tile=4,
                  data_window=(2, 1, 5, 4), display=(8, 6))
    part = exr.read_header(p).parts[0]
    assert part.tiled and (part.width, part.height) == (8, 6)
    assert (part.x, part.y, part.data_width, part.data_height) == (2, 1, 5, 4)
    got = exr.read_channels(p, [(0, "G")], fill={(0, "G"): -1.0})[(0, "G")]
    assert got.shape == (6, 8)
    assert np.array_equal(got[1:5, 2:7], g)
    assert (got[0] == -1).all() and (got[:, :2] == -1).all() and (got[:, 7] == -1).all()
    mask = part.data_mask()
    assert mask.sum() == 20 and mask[1, 2] and not mask[0, 2]


def test_overscan_data_window_is_cropped(tmp_path):
    (r,) = planes(8, 10, 1)
    p = str(tmp_path / "o.exr")
    exr.write_exr(p, {"R": r}, {"R": "float"}, data_window=(-1, -1, 10, 8), display=(8, 6))
    got = exr.read_channels(p, [(0, "R")])[(0, "R")]
    assert got.shape == (6, 8) and np.array_equal(got, r[1:7, 1:9])


def test_multi_part(tmp_path):
    a, b, c = planes()
    p = str(tmp_path / "m.exr")
    exr.write_parts(p, [dict(channels={"R": a, "G": b}, name="rgba", view="left",
                             attributes={"owner": "me"}),
                        dict(channels={"Z": c}, types={"Z": "float"}, name="depth")])
    h = exr.read_header(p)
    assert [x.name for x in h.parts] == ["rgba", "depth"]
    assert h.parts[0].view == "left" and h.parts[1].view is None
    assert [(i, n) for i, n, _ in h.all_channels()] == [(0, "G"), (0, "R"), (1, "Z")] or \
        [(i, n) for i, n, _ in h.all_channels()] == [(0, "R"), (0, "G"), (1, "Z")]
    got = exr.read_channels(p, [(1, "Z"), (0, "G")], h)
    assert np.array_equal(got[(1, "Z")], c)
    assert np.allclose(got[(0, "G")], b, rtol=2 ** -10)


def test_attribute_types_carried(tmp_path):
    (r,) = planes(n=1)
    p = str(tmp_path / "a.exr")
    exr.write_exr(p, {"R": r}, None, {"screenWindowCenter": [0.5, 0.25], "owner": "studio",
                                      "fgen:alpha": 0.5, "frameCount": 3,
                                      "smpte:TimeCode": [1, 2], "nested": {"a": 1},
                                      "m": np.eye(4).ravel().tolist()},
                  attribute_types={"smpte:TimeCode": "timecode"})
    part = exr.read_header(p).parts[0]
    a, t = part.attributes, part.attr_types
    assert t["screenWindowCenter"] == "float2" and a["screenWindowCenter"] == [0.5, 0.25]
    assert t["smpte:TimeCode"] == "timecode" and t["m"] == "matrix"
    assert a["fgen:alpha"] == 0.5 and a["frameCount"] == 3
    assert a["nested"] == '{"a": 1}'
    # and again through the recorded types: identical
    q = str(tmp_path / "b.exr")
    exr.write_exr(q, {"R": r}, None, a, attribute_types=t)
    part2 = exr.read_header(q).parts[0]
    for k in ("screenWindowCenter", "smpte:TimeCode", "m", "fgen:alpha"):
        assert part2.attributes[k] == a[k] and part2.attr_types[k] == t[k]


def test_standard_attribute_types_without_type_table(tmp_path):
    """A generated frame's header may carry values without their types: standard OpenEXR
    attributes still get the right ones."""
    (r,) = planes(n=1)
    p = str(tmp_path / "s.exr")
    chroma = [0.64, 0.33, 0.3, 0.6, 0.15, 0.06, 0.3127, 0.329]
    exr.write_exr(p, {"R": r}, None, {"chromaticities": chroma, "smpte:TimeCode": [1, 2],
                                      "framesPerSecond": [24, 1], "PixelAspectRatio": 1})
    part = exr.read_header(p).parts[0]
    t = part.attr_types
    assert t["chromaticities"] == "float[8]" and t["smpte:TimeCode"] == "timecode"
    assert t["framesPerSecond"] == "rational" and t["PixelAspectRatio"] == "float"
    assert np.allclose(part.attributes["chromaticities"], chroma)


def test_atomic_write_leaves_no_temp_and_plain_permissions(tmp_path):
    (r,) = planes(n=1)
    p = str(tmp_path / "a.exr")
    exr.write_exr(p, {"R": r})
    assert os.listdir(tmp_path) == ["a.exr"]
    mode = stat.S_IMODE(os.stat(p).st_mode)
    umask = os.umask(0)
    os.umask(umask)
    assert mode == 0o666 & ~umask


def test_failed_write_cleans_up(tmp_path):
    (r,) = planes(n=1)
    (tmp_path / "a.exr").mkdir()  # the final rename cannot replace a folder
    with pytest.raises(OutputError, match="cannot rename"):
        exr.write_exr(str(tmp_path / "a.exr"), {"R": r})
    assert os.listdir(tmp_path) == ["a.exr"]  # no temporary left behind
    with pytest.raises(OutputError, match="nothing to write"):
        exr.write_exr(str(tmp_path / "b.exr"), {})


@pytest.mark.parametrize("comp", ["zip", "piz", "none", "rle", "zips", "pxr24", "b44",
                                  "dwaa", "zstd"])
def test_compressions(tmp_path, comp):
    (r,) = planes(n=1)
    p = str(tmp_path / "c.exr")
    exr.write_exr(p, {"R": r}, {"R": "float"}, compression=comp)
    assert exr.read_header(p).attributes["compression"].startswith(comp)
    got = exr.read_channels(p, [(0, "R")])[(0, "R")]
    if comp in ("zip", "piz", "none", "rle", "zips", "zstd"):
        assert np.array_equal(got, r)  # lossless
    else:
        assert np.allclose(got, r, rtol=0.05, atol=0.05)


def test_not_exr_and_truncated(tmp_path):
    bad = tmp_path / "x.exr"
    bad.write_bytes(b"P6\n2 2\n255\n" + bytes(12))
    with pytest.raises(InputError, match="not an OpenEXR file") as e:
        exr.read_header(str(bad))
    assert str(bad) in e.value.message
    r, g, z = planes(64, 64)
    p = str(tmp_path / "full.exr")
    exr.write_exr(p, {"R": r, "G": g, "Z": z}, compression="none")
    data = open(p, "rb").read()
    half = tmp_path / "half.exr"
    half.write_bytes(data[: len(data) // 2])
    h = exr.read_header(str(half))  # header intact
    with pytest.raises(InputError, match="truncated or corrupt"):
        exr.read_channels(str(half), [(0, "R")], h)
    short = tmp_path / "short.exr"
    short.write_bytes(data[:60])
    with pytest.raises(InputError, match="truncated or corrupt header"):
        exr.read_header(str(short))
    with pytest.raises(InputError, match="file not found"):
        exr.read_header(str(tmp_path / "none.exr"))
    with pytest.raises(InputError, match="missing channel"):
        exr.read_channels(p, [(0, "Q")])


def _both_writers(tmp_path, monkeypatch, parts, **kw):
    """Write the parts with the OpenEXR writer and with OpenImageIO; their headers."""
    p_fast, p_oiio = str(tmp_path / "fast.exr"), str(tmp_path / "oiio.exr")
    used = []
    real = exr._write_openexr

    def spy(*a, **k):
        used.append(real(*a, **k))
        return used[-1]

    monkeypatch.setattr(exr, "_write_openexr", spy)
    exr.write_parts(p_fast, parts, **kw)
    monkeypatch.setattr(exr, "_openexr", lambda: None)
    exr.write_parts(p_oiio, parts, **kw)
    monkeypatch.undo()
    return p_fast, p_oiio, used


@pytest.mark.skipif(exr._openexr() is None, reason="OpenEXR binding not installed")
def test_openexr_writer_matches_openimageio(tmp_path, monkeypatch):
    """The fast writer (OpenEXR's binding) gives what OpenImageIO writes: the same
    channels and types, pixels, data and display windows, parts, and every attribute with
    its type (fgen's own, matrices, vectors, OpenImageIO's names for standard ones)."""
    a, b, c = planes(5, 7, 3, seed=3)
    a[0, 0], b[1, 1] = np.nan, np.inf  # non-finite values, and one beyond half's range
    a[2, 2] = 1e6
    attrs = {"fgen:alpha": 0.5, "fgen:n": 3, "fgen:s": "text", "owner": "studio",
             "worldToCamera": np.eye(4, dtype=np.float32) * 2, "v3": [1.0, 2.0, 3.0],
             "screenWindowCenter": [0.5, 0.25], "names": ["l", "r"], "nested": {"a": 1},
             "ImageDescription": "desc", "PixelAspectRatio": 1.0, "m33": np.eye(3).tolist()}
    parts = [dict(channels={"R": a, "G": b, "Z": c}, types={"Z": "float"}, attributes=attrs,
                  data_window=(1, 2, 7, 5), display=(9, 8))]
    fast, slow, used = _both_writers(tmp_path, monkeypatch, parts)
    assert used == [True]
    hf, hs = exr.read_header(fast).parts[0], exr.read_header(slow).parts[0]
    assert dict(zip(hf.channels, hf.formats)) == dict(zip(hs.channels, hs.formats))
    assert (hf.x, hf.y, hf.data_width, hf.data_height, hf.width, hf.height) == \
        (hs.x, hs.y, hs.data_width, hs.data_height, hs.width, hs.height) == (1, 2, 7, 5, 9, 8)
    assert hf.attr_types == hs.attr_types
    assert json_equal(hf.attributes, hs.attributes)
    gf = exr.read_channels(fast, [(0, "R"), (0, "G"), (0, "Z")])
    gs = exr.read_channels(slow, [(0, "R"), (0, "G"), (0, "Z")])
    for k in gf:
        assert np.array_equal(gf[k], gs[k], equal_nan=True)
    # multi-part with views
    parts = [dict(channels={"R": a}, name="rgba", view="left"),
             dict(channels={"Z": c}, types={"Z": "float"}, name="depth", view="right")]
    fast, slow, used = _both_writers(tmp_path, monkeypatch, parts)
    assert used == [True]
    hf, hs = exr.read_header(fast), exr.read_header(slow)
    assert [(p.name, p.view) for p in hf.parts] == [(p.name, p.view) for p in hs.parts] == \
        [("rgba", "left"), ("depth", "right")]


def json_equal(x, y) -> bool:
    import json

    return json.dumps(x, sort_keys=True, default=str) == json.dumps(y, sort_keys=True,
                                                                     default=str)


@pytest.mark.skipif(exr._openexr() is None, reason="OpenEXR binding not installed")
def test_openexr_writer_leaves_exotic_types_to_openimageio(tmp_path, monkeypatch):
    """A timecode (or tiles, or a compression level) is written by OpenImageIO, exactly."""
    (r,) = planes(n=1)
    used = []
    real = exr._write_openexr
    monkeypatch.setattr(exr, "_write_openexr", lambda *a, **k: used.append(real(*a, **k))
                        or used[-1])
    p = str(tmp_path / "t.exr")
    exr.write_exr(p, {"R": r}, None, {"smpte:TimeCode": [1, 2]},
                  attribute_types={"smpte:TimeCode": "timecode"})
    assert used == [False]
    assert exr.read_header(p).parts[0].attr_types["smpte:TimeCode"] == "timecode"
    assert os.listdir(tmp_path) == ["t.exr"]  # the fast writer's temporary is gone


@pytest.mark.skipif(exr._openexr() is None, reason="OpenEXR binding not installed")
def test_openexr_reader_matches_openimageio(tmp_path, monkeypatch):
    """The one-pass reader (OpenEXR's binding) returns what OpenImageIO's span reads
    return: mixed types, data windows with fill, overscan borders, parts."""
    a, b, c = planes(6, 9, 3, seed=5)
    a[0, 0], c[1, 1] = np.nan, -np.inf
    p = str(tmp_path / "r.exr")
    exr.write_parts(p, [dict(channels={"R": a, "G": b, "Z": c}, types={"Z": "float"},
                             data_window=(-1, 1, 9, 6), display=(8, 8), name="rgba"),
                        dict(channels={"mv.x": c}, types={"mv.x": "float"}, name="mv",
                             data_window=(-1, 1, 9, 6), display=(8, 8))])
    want = [(0, "R"), (0, "Z"), (1, "mv.x")]
    calls = []
    real = exr._read_openexr
    monkeypatch.setattr(exr, "_read_openexr", lambda *x: calls.append(real(*x)) or calls[-1])
    bf = {}
    fast = exr.read_channels(p, want, fill={(0, "Z"): 7.0}, borders=bf)
    assert calls and calls[0] is not None
    monkeypatch.setattr(exr, "_openexr", lambda: None)
    bs = {}
    slow = exr.read_channels(p, want, fill={(0, "Z"): 7.0}, borders=bs)
    for k in want:
        assert fast[k].dtype == np.float32 and np.array_equal(fast[k], slow[k], equal_nan=True)
    assert bf.keys() == bs.keys() and all(np.array_equal(bf[k][0], bs[k][0], equal_nan=True)
                                          and bf[k][1:] == bs[k][1:] for k in bf)


@pytest.mark.skipif(exr._openexr() is None, reason="OpenEXR binding not installed")
def test_damaged_file_prints_nothing_and_names_itself(tmp_path, capfd):
    """A damaged chunk: the OpenEXR library's own messages never reach the terminal; the
    file is read again by OpenImageIO, whose error names it."""
    r = np.random.default_rng(1).random((64, 64), dtype=np.float32)
    p = str(tmp_path / "d.exr")
    exr.write_exr(p, {"R": r, "G": r[::-1].copy()}, {"R": "float", "G": "float"})
    data = bytearray(open(p, "rb").read())
    mid = len(data) // 2
    data[mid:mid + 200] = b"\x55" * 200
    open(p, "wb").write(bytes(data))
    with pytest.raises(InputError) as e:
        exr.read_channels(p, [(0, "R"), (0, "G")])
    assert "d.exr" in str(e.value)
    out, err = capfd.readouterr()
    assert "EXR_ERR" not in out + err and "Warning" not in out + err


def test_captured_output_of_others_goes_through(capfd):
    """While the library's messages are held back, other output is only delayed."""
    with exr._library_output_captured():
        os.write(2, b"progress 1/3\n")
        os.write(2, b"x.exr: (EXR_ERR_CORRUPT_CHUNK) Unable to decompress\n")
        os.write(1, b"Warning: Exception raised reading pixel data for part 0 - x\n")
        os.write(1, b"result\n")
        print("Warning: Exception raised reading pixel data for part 1 - y")
        print("more", flush=True)
    out, err = capfd.readouterr()
    # descriptor 1 untouched; the binding's line through Python (sys.stdout) dropped
    assert out == "Warning: Exception raised reading pixel data for part 0 - x\nresult\n" \
        "more\n"
    assert err == "progress 1/3\n"


def test_capture_without_a_temporary_folder_reads_as_is(monkeypatch):
    """No writable temporary folder: the library's lines are not held back, nothing else
    changes, and no file descriptor is left open."""
    import tempfile

    def refuse(*a, **k):
        raise OSError("read-only")

    monkeypatch.setattr(tempfile, "TemporaryFile", refuse)
    before = len(os.listdir("/proc/self/fd")) if os.path.isdir("/proc/self/fd") else None
    for _ in range(3):
        with exr._library_output_captured():
            pass
    if before is not None:
        assert len(os.listdir("/proc/self/fd")) == before
