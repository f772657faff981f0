"""Sequence discovery (issue #2 item 3): naming styles, frame ranges, several sequences,
gaps."""
from __future__ import annotations

import os

import pytest
from hypothesis import given, strategies as st

from fgcli.errors import InputError, UsageError
from fgcli.io.sequence import discover, parse_frames, parse_name


def touch(folder, *names):
    os.makedirs(folder, exist_ok=True)
    for n in names:
        open(os.path.join(folder, n), "wb").close()
    return str(folder)


@pytest.mark.parametrize("names,prefix,frames", [
    (["name.1001.exr", "name.1002.exr", "name.1003.exr"], "name.", [1001, 1002, 1003]),
    (["name_0001.exr", "name_0002.exr"], "name_", [1, 2]),
    (["frame_0001.exr", "frame_0002.exr"], "frame_", [1, 2]),
    (["0001.exr", "0002.exr"], "", [1, 2]),
    (["shot-0009.exr", "shot-0010.exr"], "shot-", [9, 10]),
    (["a.8.exr", "a.9.exr", "a.10.exr"], "a.", [8, 9, 10]),  # unpadded: one sequence
    (["b.9999.exr", "b.10000.exr"], "b.", [9999, 10000]),  # past the padding
    (["n.-001.exr", "n.000.exr", "n.001.exr"], "n.", [-1, 0, 1]),
    (["up.0001.EXR", "up.0002.EXR"], "up.", [1, 2]),
])
def test_naming_styles(tmp_path, names, prefix, frames):
    seq = discover(touch(tmp_path / "s", *names, "notes.txt", "cameras.json"))
    assert seq.prefix == prefix and seq.frames == frames
    assert os.path.basename(seq.path_for(frames[0])) == names[0].replace(".EXR", ".exr")


def test_step_and_pattern(tmp_path):
    seq = discover(touch(tmp_path / "s", "x.1001.exr", "x.1003.exr", "x.1005.exr"))
    assert seq.step == 2 and seq.pattern == "x.####.exr" and seq.missing() == []


def test_temp_files_ignored(tmp_path):
    seq = discover(touch(tmp_path / "s", "x.0001.exr", ".fgen-tmp-abc.exr"))
    assert seq.frames == [1]


def test_several_sequences_listed_and_pattern_picks(tmp_path):
    d = touch(tmp_path / "s", "a.0001.exr", "a.0002.exr", "b_0001.exr", "b_0002.exr",
              "b_0003.exr")
    with pytest.raises(InputError) as e:
        discover(d)
    msg = e.value.message
    assert "a.####.exr (2 frames 1-2)" in msg and "b_####.exr (3 frames 1-3)" in msg
    assert "--pattern" in msg
    for pat in ("b_####.exr", "b_", "b_*.exr"):
        assert discover(d, pattern=pat).frames == [1, 2, 3]
    with pytest.raises(InputError, match="no sequence matches"):
        discover(d, pattern="zzz*")


def test_gaps_error_names_missing_frames(tmp_path):
    d = touch(tmp_path / "s", "g.0001.exr", "g.0002.exr", "g.0005.exr")
    with pytest.raises(InputError) as e:
        discover(d)
    assert "missing frames: 3, 4" in e.value.message and "--allow-gaps" in e.value.message
    assert discover(d, allow_gaps=True).frames == [1, 2, 5]


def test_frames_selection(tmp_path):
    d = touch(tmp_path / "s", *[f"f.{n}.exr" for n in range(1001, 1011)])
    assert discover(d, frames="1001-1009x2").frames == [1001, 1003, 1005, 1007, 1009]
    assert discover(d, frames="1001-1009x2").step == 2
    assert discover(d, frames="1002,1004-1005").frames == [1002, 1004, 1005]
    with pytest.raises(InputError, match="not on disk: 1011"):
        discover(d, frames="1009-1011")


def test_parse_frames():
    assert parse_frames("1001-1010x3") == [1001, 1004, 1007, 1010]
    assert parse_frames("5") == [5]
    assert parse_frames("1,3,5-7") == [1, 3, 5, 6, 7]
    assert parse_frames("10-7") == [10, 9, 8, 7]
    assert parse_frames("-3--1") == [-3, -2, -1]
    for bad in ("a-b", "1-5x0", "1..5"):
        with pytest.raises(UsageError):
            parse_frames(bad)


@given(st.integers(-500, 5000), st.integers(0, 200), st.integers(1, 7))
def test_parse_frames_matches_range(a, n, step):
    assert parse_frames(f"{a}-{a + n}x{step}") == list(range(a, a + n + 1, step))


def test_parse_name():
    assert parse_name("shot.v2.0010.exr") == ("shot.v2.", "0010", 10)
    assert parse_name("readme.txt") is None and parse_name("x.exr") is None


def test_empty_and_missing_folder(tmp_path):
    d = touch(tmp_path / "empty", "readme.txt")
    with pytest.raises(InputError, match="no EXR frames found"):
        discover(d)
    with pytest.raises(InputError, match="not a folder"):
        discover(str(tmp_path / "nope"))
