"""Runs that survive the real world: farm chunks (--chunk K/N), stale temporary files of
killed runs, several sequences per command, the recorded command line, and the plan that
splits a sequence. The SIGKILL and Dask tests are in test_kill.py and test_dask.py."""
from __future__ import annotations

import filecmp
import os
import shutil
import time
from fractions import Fraction

import pytest
from click.testing import CliRunner

from fgcli.cli import cli
from fgcli.commands._generate import recorded_command
from fgcli.io import atomic
from fgcli.runner import chunk_slice, plan_outputs, warmup_jobs

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ORBIT = os.path.join(ROOT, "sample_data", "orbit", "input")


def _run(args):
    r = CliRunner().invoke(cli, args)
    assert r.exit_code == 0, r.output
    return r


def exr_names(folder):
    return sorted(f for f in os.listdir(folder) if f.endswith(".exr"))


def assert_same_frames(a, b):
    names = exr_names(a)
    assert names and names == exr_names(b)
    for n in names:
        assert filecmp.cmp(os.path.join(a, n), os.path.join(b, n), shallow=False), n


# ------------------------------------------------------------------------------ the plan

@pytest.mark.parametrize("total", [0, 1, 5, 16, 17])
@pytest.mark.parametrize("n", [1, 3, 7, 20])
def test_chunk_slices_cover_every_output_once(total, n):
    got = [i for k in range(1, n + 1) for i in chunk_slice(total, k, n)]
    assert got == list(range(total))
    sizes = [len(chunk_slice(total, k, n)) for k in range(1, n + 1)]
    assert max(sizes) - min(sizes) <= 1  # near-equal parts


def test_plan_parts_are_contiguous_in_output_numbers():
    nums = list(range(0, 33, 2))
    full = plan_outputs(nums, 2, "interp", [Fraction(1, 3), Fraction(2, 3)], emit="all")
    parts = [plan_outputs(nums, 2, "interp", [Fraction(1, 3), Fraction(2, 3)], emit="all",
                          chunk=(k, 5))["outputs"] for k in range(1, 6)]
    assert sum(parts, []) == full["outputs"] == sorted(full["outputs"])
    assert len(full["outputs"]) == 17 + 32


def test_warmup_replays_what_recurrent_state_needs():
    assert warmup_jobs([5, 6], 0) == [5, 6]
    assert warmup_jobs([5, 9], 2) == [3, 4, 5, 7, 8, 9]
    assert warmup_jobs([4], None) == [0, 1, 2, 3, 4]
    assert warmup_jobs([], None) == []


def test_recorded_command_leaves_out_execution_only_options():
    argv = ["interpolate", "in", "out", "--chunk", "2/3", "--resume", "--pipeline", "mob-fgsr",
            "--executor=dask", "--scheduler", "tcp://h:1", "--no-progress", "--factor", "2",
            "--overwrite", "--json", "x.json", "--workers", "2"]
    assert recorded_command(argv) == "fgen interpolate in out --pipeline mob-fgsr --factor 2"


@pytest.mark.parametrize("bad", ["0/3", "4/3", "3", "a/b", "1/0"])
def test_bad_chunk_is_a_usage_error(tmp_path, bad):
    r = CliRunner().invoke(cli, ["interpolate", ORBIT, str(tmp_path / "o"), "--chunk", bad])
    assert r.exit_code == 2 and "--chunk" in r.output


# ------------------------------------------------------------------------- farm chunks

@pytest.mark.parametrize("mode, extra", [
    ("interpolate", []),
    ("extrapolate", ["--alpha", "0.5"]),
    ("interpolate", ["--factor", "3", "--emit", "all"]),
])
def test_chunks_are_byte_identical_to_one_run(tmp_path, mode, extra):
    """N = 1, 3, 7 chunk runs write exactly the frames of one run, byte for byte (the
    recorded command line leaves --chunk out); no frame twice, none skipped."""
    base = [mode, ORBIT, str(tmp_path / "out"), "--frames", "0-16x2", "--no-progress"] + extra
    _run(base)
    os.rename(tmp_path / "out", tmp_path / "ref")
    for n in (1, 3, 7):
        shutil.rmtree(tmp_path / "out", ignore_errors=True)
        made = []
        for k in range(1, n + 1):
            before = set(exr_names(tmp_path / "out")) if (tmp_path / "out").exists() else set()
            _run(base + ["--chunk", f"{k}/{n}"])
            new = set(exr_names(tmp_path / "out")) - before
            made.append(new)
            assert (tmp_path / "out" / f"fgen-run.chunk-{k}-of-{n}.json").exists()
        names = [x for m in made for x in m]
        assert len(names) == len(set(names))  # no frame made twice
        assert_same_frames(tmp_path / "ref", tmp_path / "out")


def test_a_chunk_refuses_only_its_own_existing_outputs(tmp_path):
    out = str(tmp_path / "out")
    base = ["interpolate", ORBIT, out, "--frames", "0-8x2", "--no-progress"]
    _run(base + ["--chunk", "1/2"])
    _run(base + ["--chunk", "2/2"])  # the other part exists: not its business
    r = CliRunner().invoke(cli, base + ["--chunk", "1/2"])
    assert r.exit_code == 3 and "outputs exist" in r.output


# ---------------------------------------------------------------- stale temporary files

def test_stale_temporary_files_are_told_apart_and_removed(tmp_path):
    import subprocess
    import sys

    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()  # a pid that is gone
    host = atomic._host()
    dead = tmp_path / f".fgen-tmp-{p.pid}@{host}@abc.exr"
    mine = tmp_path / f".fgen-tmp-{os.getpid()}@{host}@abc.exr"
    other = tmp_path / f".fgen-tmp-{p.pid}@another-host@abc.exr"
    old = tmp_path / ".fgen-tmp-legacy1234.exr"
    keep = tmp_path / "frame.0001.exr"
    for f in (dead, mine, other, old, keep):
        f.write_bytes(b"x")
    past = time.time() - 2 * atomic.STALE_AFTER_S
    os.utime(old, (past, past))
    assert sorted(atomic.remove_stale(str(tmp_path))) == sorted([dead.name, old.name])
    assert mine.exists() and other.exists() and keep.exists()
    os.utime(other, (past, past))  # another host's writer: stale once nothing touches it
    assert atomic.remove_stale(str(tmp_path)) == [other.name]


def test_any_run_into_a_folder_removes_stale_temporaries(tmp_path):
    import subprocess
    import sys

    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    out = tmp_path / "out"
    out.mkdir()
    stale = out / f".fgen-tmp-{p.pid}@{atomic._host()}@x1.exr"
    stale.write_bytes(b"half a frame")
    r = _run(["interpolate", ORBIT, str(out), "--frames", "0-4x2", "--no-progress"])
    assert not stale.exists() and "removed 1 temporary" in r.output
    assert not [f for f in os.listdir(out) if f.startswith(".fgen-tmp-")]


def test_written_files_get_unique_temporary_names(tmp_path):
    a = atomic.make_temp(str(tmp_path), ".exr")
    b = atomic.make_temp(str(tmp_path), ".exr")
    assert a != b and os.path.basename(a).startswith(atomic.temp_prefix())
    atomic.write_text(str(tmp_path / "x.json"), "{}")
    assert (tmp_path / "x.json").read_text() == "{}"


# ------------------------------------------------------------------ several sequences

def _two_sequences(tmp_path):
    """A folder with two sequences (a.*, b.*) and two folders with one each."""
    both = tmp_path / "both"
    both.mkdir()
    for i, name in enumerate(sorted(exr_names(ORBIT))[:3]):
        n = int(name.split(".")[1])
        for pre in ("a", "b"):
            shutil.copy(os.path.join(ORBIT, name), both / f"{pre}.{n:04d}.exr")
    for pre in ("a", "b"):
        d = tmp_path / f"shot_{pre}"
        d.mkdir()
        for f in os.listdir(both):
            if f.startswith(pre + "."):
                shutil.copy(both / f, d / f)
    return both


def test_several_folders_and_a_pattern_write_one_subfolder_each(tmp_path):
    both = _two_sequences(tmp_path)
    _run(["interpolate", str(tmp_path / "shot_a"), str(tmp_path / "shot_b"),
          str(tmp_path / "o1"), "--no-progress"])
    assert exr_names(tmp_path / "o1" / "shot_a") == ["a.0001.exr", "a.0003.exr"]
    assert exr_names(tmp_path / "o1" / "shot_b") == ["b.0001.exr", "b.0003.exr"]
    _run(["interpolate", str(both), str(tmp_path / "o2"), "--pattern", "*.exr", "--no-progress"])
    assert exr_names(tmp_path / "o2" / "a") == ["a.0001.exr", "a.0003.exr"]
    assert_same_frames(tmp_path / "o2" / "b", tmp_path / "o1" / "shot_b")
    r = CliRunner().invoke(cli, ["interpolate", str(both), str(tmp_path / "o3"), "--no-progress"])
    assert r.exit_code == 1 and "--pattern" in r.output  # several, none picked: say so
