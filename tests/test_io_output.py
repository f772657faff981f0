"""Writers and output folders (issue #2 item 6)."""
from __future__ import annotations

import os
import sys

import numpy as np
import pytest
import torch

from fgcli import __version__
from fgcli.errors import EXIT_OUTPUT, OutputError
from fgcli.frame import Frame
from fgcli.io import exr, output
from fgcli.io.frames import read_frame
from fgcli.io.options import open_input, open_output
from fgcli.io.output import OutputFolder, fgen_attributes


def frame(s, n=1, **kw):
    return Frame(number=n, color=torch.from_numpy(s["color"]),
                 depth=torch.from_numpy(s["depth"]), mv=torch.from_numpy(s["mv"]), **kw)


def test_refuses_input_folder(tmp_path):
    with pytest.raises(OutputError, match="input folder") as e:
        OutputFolder(str(tmp_path), input_folder=str(tmp_path / "." ))
    assert e.value.exit_code == EXIT_OUTPUT
    os.symlink(tmp_path, tmp_path.parent / (tmp_path.name + "-link"))
    with pytest.raises(OutputError, match="input folder"):
        OutputFolder(str(tmp_path.parent / (tmp_path.name + "-link")), str(tmp_path))


def test_creates_folder_and_names(tmp_path):
    out = OutputFolder(str(tmp_path / "a" / "b"), str(tmp_path), prefix="shot.", padding=4)
    assert os.path.isdir(out.path)
    assert out.path_for(7) == str(tmp_path / "a" / "b" / "shot.0007.exr")
    assert out.path_for(-3).endswith("shot.-0003.exr")
    assert out.path_for("x.1001.exr") == str(tmp_path / "a" / "b" / "x.1001.exr")
    assert out.path_for("mid") == str(tmp_path / "a" / "b" / "mid.exr")


def test_unwritable_output(tmp_path, monkeypatch):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(OutputError, match="cannot create output folder") as e:
        OutputFolder(str(blocker / "out"), str(tmp_path / "in"))
    assert e.value.exit_code == EXIT_OUTPUT
    with pytest.raises(OutputError, match="not a folder"):
        OutputFolder(str(blocker), str(tmp_path / "in"))
    # a folder that exists but refuses new files (simulated: tests may run as root)
    ro = tmp_path / "ro"
    ro.mkdir()

    def deny(*a, **k):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(output.atomic, "make_temp", deny)
    with pytest.raises(OutputError, match="not writable: Permission denied"):
        OutputFolder(str(ro), str(tmp_path / "in"))


@pytest.mark.skipif(hasattr(os, "geteuid") and os.geteuid() == 0,
                    reason="root ignores folder permissions")
def test_unwritable_output_real_permissions(tmp_path):  # pragma: no cover - non-root only
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        with pytest.raises(OutputError, match="not writable"):
            OutputFolder(str(ro), str(tmp_path / "in"))
    finally:
        ro.chmod(0o700)


def test_should_write_overwrite_resume(tmp_path, tiny_scene):
    s = tiny_scene(1)
    out = OutputFolder(str(tmp_path / "o"), str(tmp_path / "in"))
    p = out.path_for(1)
    assert out.should_write(p)
    out.write(p, frame(s))
    with pytest.raises(OutputError, match="output exists") as e:
        out.should_write(p)
    assert p in e.value.message
    with pytest.raises(OutputError, match="outputs exist: frame.0001.exr"):
        out.check_all([p, out.path_for(2)])
    assert OutputFolder(out.path, None, overwrite=True).should_write(p)
    res = OutputFolder(out.path, None, resume=True)
    assert not res.should_write(p) and res.skipped == [p]
    res.check_all([p])  # no error when resuming
    # an incomplete (truncated) file is rewritten on resume
    bad = out.path_for(2)
    with open(p, "rb") as fh:
        data = fh.read()
    with open(bad, "wb") as fh:
        fh.write(data[:40])
    assert res.should_write(bad)
    res.write(bad, frame(s, 2))
    assert output.is_complete(bad)


def test_write_rejects_paths_elsewhere(tmp_path, tiny_scene):
    out = OutputFolder(str(tmp_path / "o"), None)
    with pytest.raises(OutputError, match="not inside the output folder"):
        out.write(str(tmp_path / "x.exr"), frame(tiny_scene(0)))
    assert out.write("bare.exr", frame(tiny_scene(0))) == str(tmp_path / "o" / "bare.exr")


def test_fgen_attributes_and_metadata_carried(tmp_path, tiny_scene, monkeypatch):
    monkeypatch.setattr(sys, "argv", ["fgen", "interpolate", "in/", "out/"])
    a = fgen_attributes(pipeline="mv-interp", alpha=0.5, source_frames=[1001, 1002],
                        seed=3)
    assert a == {"fgen:version": __version__, "fgen:command_line": "fgen interpolate in/ out/",
                 "fgen:pipeline": "mv-interp", "fgen:alpha": 0.5,
                 "fgen:source_frames": "1001,1002", "fgen:seed": 3}
    s = tiny_scene(1)
    src = str(tmp_path / "src.0001.exr")
    exr.write_exr(src, {"R": s["color"][0], "G": s["color"][1], "B": s["color"][2],
                        "mv.x": s["mv"][0], "mv.y": s["mv"][1]}, None,
                  {"owner": "studio", "screenWindowCenter": [0.0, 0.0],
                   "smpte:TimeCode": [1, 2], "multiView": ["left"]},
                  attribute_types={"smpte:TimeCode": "timecode"})
    f = read_frame(src, 1)
    out = OutputFolder(str(tmp_path / "o"), str(tmp_path))
    p = out.write(out.path_for(1), f, attributes=a, compression="piz")
    h = exr.read_header(p).parts[0]
    assert h.attributes["Copyright"] == "studio"  # OIIO's name for owner
    assert h.attr_types["screenWindowCenter"] == "float2"
    assert h.attr_types["smpte:TimeCode"] == "timecode"
    assert h.attributes["fgen:pipeline"] == "mv-interp"
    assert h.attributes["fgen:source_frames"] == "1001,1002"
    assert h.attributes["fgen:command_line"] == "fgen interpolate in/ out/"
    assert h.attributes["compression"] == "piz"
    assert "multiView" not in h.attributes


def test_half_and_float_output(tmp_path, tiny_scene):
    s = tiny_scene(1)
    out = OutputFolder(str(tmp_path / "o"), None, half=False)
    p = out.write(out.path_for(1), frame(s))
    assert set(exr.read_header(p).parts[0].formats) == {"float"}
    p = out.write(out.path_for(2), frame(s), half=True)
    fm = dict(zip(*[getattr(exr.read_header(p).parts[0], k) for k in ("channels", "formats")]))
    assert fm["R"] == "half" and fm["Z"] == "float" and fm["mv.x"] == "float"


def test_open_output_from_reader(tmp_path, tiny_scene):
    s = tiny_scene(1)
    src = tmp_path / "in"
    src.mkdir()
    for n in (1001, 1002):
        exr.write_exr(str(src / f"shot_{n}.exr"), {"R": s["color"][0], "G": s["color"][1],
                                                    "B": s["color"][2]})
    r = open_input(str(src), unused_option=1)
    with pytest.raises(OutputError, match="input folder"):
        open_output(str(src), r)
    out = open_output(str(tmp_path / "o"), r, out_layout="input", use_float=True,
                      compression="zips", irrelevant=True)
    assert out.layout is r.layout and out.half is False and out.compression == "zips"
    assert os.path.basename(out.path_for(1003)) == "shot_1003.exr"
    assert np.isfinite(r.read(1001).color.numpy()).all()


def test_a_truncated_output_is_not_complete(tmp_path):
    """--resume rewrites an output whose header survived but whose pixels did not."""
    import torch

    from fgcli.frame import Frame
    from fgcli.io.frames import write_frame
    from fgcli.io.output import is_complete

    p = tmp_path / "f.0001.exr"
    write_frame(str(p), Frame(number=1, color=torch.rand(3, 40, 64), depth=torch.rand(1, 40, 64),
                              mv=torch.rand(2, 40, 64)))
    assert is_complete(str(p))
    data = p.read_bytes()
    p.write_bytes(data[: len(data) // 2])
    assert not is_complete(str(p))
