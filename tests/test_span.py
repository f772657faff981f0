"""--frames with a step larger than the files' step: each kept frame's vectors are chained
through the skipped files on disk so they span the selected interval (what a renderer at
the lower rate writes), and the pipeline sees the same frames as a folder holding only the
kept frames with those vectors."""
from __future__ import annotations

import os

import pytest
import torch
from click.testing import CliRunner

from fgcli.cli import cli
from fgcli.io.frames import read_frame, write_frame
from fgcli.io.reader import SequenceReader

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


@pytest.fixture(scope="module")
def rates(tmp_path_factory):
    from fgcli.synth import load_scene, render_sequence

    tmp = tmp_path_factory.mktemp("span")
    f = os.path.join(ROOT, "sample_data", "scenes", "throw.toml")
    half = load_scene(f, size=(64, 36), frames=4, spp=1)
    full = load_scene(f, size=(64, 36), frames=7, fps=2 * half.fps, spp=1)
    render_sequence(half, tmp / "half", progress=False)
    render_sequence(full, tmp / "full", progress=False)
    return tmp


def test_selected_step_chains_vectors_like_a_lower_rate_render(rates, capsys):
    sel = SequenceReader(str(rates / "full"), frames="0-6x2")
    half = SequenceReader(str(rates / "half"))  # numbered 0..3 at the lower rate
    assert sel.step == 2 and sel.disk_step == 1
    for n in sel.numbers:
        a, b = sel.read(n), half.read(n // 2)
        one_step = SequenceReader(str(rates / "full")).read(n).mv
        err = (a.mv - b.mv).norm(dim=0)
        # the true 2-step motion: twice the one-step vectors' size, matched away from
        # disocclusions and silhouettes (a few % of pixels, where chaining cannot know)
        assert err.median() < 0.02, n
        assert (err < 0.05).float().mean() > 0.97, n
        assert b.mv.norm(dim=0).median() > 1.8 * one_step.norm(dim=0).median()
    assert "vectors chained through the 1 file(s)" in capsys.readouterr().err
    assert any("chained" in x for x in sel.notes)


def test_interpolate_on_a_selection_equals_a_folder_of_the_kept_frames(rates, tmp_path):
    sel = SequenceReader(str(rates / "full"), frames="0-6x2")
    kept = tmp_path / "kept"
    kept.mkdir()
    for n in sel.numbers:
        f = sel.read(n)
        write_frame(str(kept / f"throw.{n:04d}.exr"), f.replace(camera=None))
    r = CliRunner()
    for args in (["interpolate", str(rates / "full"), str(tmp_path / "a"), "--frames", "0-6x2"],
                 ["interpolate", str(kept), str(tmp_path / "b")]):
        res = r.invoke(cli, args + ["--no-progress", "--pipeline", "mob-fgsr"])
        assert res.exit_code == 0, res.output
    names = sorted(x for x in os.listdir(tmp_path / "a") if x.endswith(".exr"))
    assert names == ["throw.0001.exr", "throw.0003.exr", "throw.0005.exr"]
    for name in names:
        a = read_frame(str(tmp_path / "a" / name), 0)
        b = read_frame(str(tmp_path / "b" / name), 0)
        # same inputs, same arithmetic; the stored vectors went through a float32 EXR
        # round trip (exact) and color through half (both sides alike): equal up to one
        # half-float step where a last-bit difference in a chained vector moves a sample
        assert torch.allclose(a.color, b.color, rtol=1e-3, atol=1e-3), name
        assert torch.allclose(a.mv, b.mv, atol=1e-4), name


def test_missing_skipped_files_leave_the_vectors_as_they_are(rates, tmp_path):
    import shutil

    part = tmp_path / "part"
    shutil.copytree(rates / "full", part)
    os.remove(part / "throw.0003.exr")  # the file between 2 and 4 is gone
    sel = SequenceReader(str(part), frames="0,2,4", allow_gaps=True)
    raw = SequenceReader(str(part), frames="4", allow_gaps=True)
    assert torch.equal(sel.read(4).mv, raw.read(4).mv)
