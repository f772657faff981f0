"""The command line says what it does (issue 61, items 2, 3, 4 and 6): output numbering on
the input's timeline, range-checked options with one-line errors, `--json -`, no library
chatter on stdout, the README's exit codes, `--set` errors naming the command line,
`eval --frames` on input/gt pairs, help in sections, --dry-run, progress in logs, --threads."""
from __future__ import annotations

import json
import os
import re

import pytest
import torch

from conftest import render_scene
from fgcli.cli import main
from fgcli.errors import EXIT_BAD_INPUT, EXIT_OUTPUT, EXIT_USAGE
from fgcli.frame import Frame
from fgcli.io.frames import write_frame
from fgcli.io.reader import SequenceReader

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


from tests._cli import fgen  # noqa: E402


def _frame(t, scale=1.0):
    d = render_scene(t, 24, 32)
    return Frame(number=t, color=torch.from_numpy(d["color"]), depth=torch.from_numpy(d["depth"]),
                 mv=torch.from_numpy(d["mv"]) * scale)


@pytest.fixture
def pair(tmp_path):
    """input/ at half rate (frames 0, 2, .., 8) and gt/ with the frames between."""
    root = tmp_path / "scene"
    (root / "input").mkdir(parents=True)
    (root / "gt").mkdir()
    for t in range(9):
        if t % 2 == 0:
            write_frame(str(root / "input" / f"s.{t:04d}.exr"), _frame(t, 2.0))
        else:
            write_frame(str(root / "gt" / f"s.{t:04d}.exr"), _frame(t))
    return root


RUN = ("--pipeline", "blend", "--backend", "torch", "--no-progress")


# ------------------------------------------------------------------- 2. numbering


def test_numbering_scaled_says_so_input_refused_sequential(pair, tmp_path, capsys):
    inp = pair / "input"
    code, _, err = fgen(capsys, "interpolate", inp, tmp_path / "a", "--factor", "4", *RUN)
    assert code == 0, err
    assert "numbered on the input's timeline x2" in err and "input frame n is output frame n*2" in err
    names = sorted(os.listdir(tmp_path / "a"))
    assert "s.0001.exr" in names and "s.0002.exr" in names  # at input frames 0.5 and 1
    a = SequenceReader(str(tmp_path / "a"), allow_gaps=True).header0.attributes
    assert float(a["fgen:input_frame"]) == 0.5 and "scaled" in a["fgen:numbering"]
    run = json.loads((tmp_path / "a" / "fgen-run.json").read_text())
    assert run["numbering"] == "scaled" and run["timeline_scale"] == 2
    # the input's own numbers: refused, saying why and what to use
    code, _, err = fgen(capsys, "interpolate", inp, tmp_path / "b", "--factor", "4",
                        "--numbering", "input", *RUN)
    assert code == EXIT_USAGE and len(err.strip().splitlines()) == 1
    assert "fall between input frame numbers" in err and "--numbering sequential" in err
    assert not (tmp_path / "b").exists()
    # ... and accepted where every generated frame has an integer number
    code, _, err = fgen(capsys, "interpolate", inp, tmp_path / "c", "--numbering", "input", *RUN)
    assert code == 0 and sorted(n for n in os.listdir(tmp_path / "c") if n.endswith(".exr")) \
        == ["s.0001.exr", "s.0003.exr", "s.0005.exr", "s.0007.exr"]
    # sequential, merged with the rendered frames: 0, 1, 2, ... in time order, no collision
    code, _, err = fgen(capsys, "interpolate", inp, tmp_path / "d", "--factor", "4",
                        "--numbering", "sequential", "--emit", "all", *RUN)
    assert code == 0, err
    r = SequenceReader(str(tmp_path / "d"))
    assert r.numbers == list(range(17))
    places = [float(r._header(n).attributes["fgen:input_frame"]) for n in r.numbers]
    assert places == [k / 2 for k in range(17)]


# ------------------------------------------------------------------- 3. checks and streams


@pytest.mark.parametrize("args", [
    ("interpolate", "IN", "OUT", "--factor", "0"),
    ("interpolate", "IN", "OUT", "--factor", "1"),
    ("extrapolate", "IN", "OUT", "--count", "0"),
    ("interpolate", "IN", "OUT", "--workers", "0", "--executor", "dask"),
    ("interpolate", "IN", "OUT", "--threads", "0"),
    ("interpolate", "IN", "OUT", "--scene-cut-threshold", "-1"),
    ("eval", "IN", "--factor", "0"),
    ("eval", "IN", "--repeat", "0"),
    ("synth", "SCENE", "OUT", "--spp", "0"),
    ("train", "mv-interp", "--data", "D", "--run", "R", "--steps", "0"),
])
def test_numeric_options_range_checked_one_line(pair, tmp_path, capsys, args):
    sub = {"IN": pair / "input", "OUT": tmp_path / "o", "SCENE": "x.toml", "D": tmp_path / "d",
           "R": tmp_path / "r"}
    code, out, err = fgen(capsys, *[sub.get(a, a) for a in args])
    assert code == EXIT_USAGE
    assert len(err.strip().splitlines()) == 1 and err.startswith("Error: ") and out == ""
    assert not (tmp_path / "o").exists()


def test_json_dash_is_stdout(pair, tmp_path, capsys):
    code, out, err = fgen(capsys, "interpolate", pair / "input", tmp_path / "o", "--json", "-",
                          *RUN)
    assert code == 0 and json.loads(out)["written"] == 4 and not os.path.exists("-")
    code, out, err = fgen(capsys, "eval", pair, "--pipeline", "blend,repeat", "--json", "-",
                          "--backend", "torch", "--no-progress", "--no-hdr-flip")
    assert code == 0 and set(json.loads(out)["pipelines"]) == {"blend", "repeat"}
    assert "| blend |" in err  # the table moves to stderr


def test_truncated_exr_prints_nothing_on_stdout(pair, capfd):
    p = pair / "input" / "s.0004.exr"
    data = p.read_bytes()
    p.write_bytes(data[: len(data) // 2])
    with pytest.raises(SystemExit) as e:
        main(["info", str(pair / "input"), "--scan", "--json"])
    out, err = capfd.readouterr()
    assert e.value.code == EXIT_BAD_INPUT and out == ""
    assert "s.0004.exr" in err and "frame 4" in err


def test_set_errors_name_the_command_line(pair, tmp_path, capsys):
    for s, says in (("splat.motoin=linear", "no option 'motoin'"),
                    ("splat.motion=cubic", "must be one of"),
                    ("nope=1", "no stage has option or id 'nope'")):
        code, _, err = fgen(capsys, "interpolate", pair / "input", tmp_path / "o",
                            "--pipeline", "mob-fgsr", "--set", s, "--dry-run")
        assert code == EXIT_USAGE and f"--set {s}:" in err and says in err
        assert ".toml" not in err  # the file is not at fault


def _readme_exit_codes():
    text = open(os.path.join(ROOT, "README.md")).read()
    table = text.split("## Errors and exit codes", 1)[1].split("\n\n", 2)[1]
    return {int(m.group(1)): m.group(2) for m in re.finditer(r"^\| (\d) \| (.*) \|$", table, re.M)}


def test_exit_codes_as_the_readme_table_says(pair, tmp_path, capsys, tiny_scene):
    table = _readme_exit_codes()
    assert set(table) == {0, 1, 2, 3}
    inp = pair / "input"
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "s.0001.exr").write_text("not an image\n")
    (tmp_path / "empty").mkdir()
    (tmp_path / "afile").write_text("x")
    gap = tmp_path / "gap"
    gap.mkdir()
    for t in (0, 1, 3):
        write_frame(str(gap / f"g.{t:04d}.exr"), _frame(t))
    existing = tmp_path / "exists"
    fgen(capsys, "interpolate", inp, existing, *RUN)
    from fgcli.io import exr

    ychan = tmp_path / "ychan"
    ychan.mkdir()
    exr.write_exr(str(ychan / "y.0001.exr"), {"Y": render_scene(0)["color"][0]})
    sizes = tmp_path / "sizes"
    sizes.mkdir()
    write_frame(str(sizes / "z.0001.exr"), _frame(0))
    d = render_scene(1, 20, 30)
    write_frame(str(sizes / "z.0002.exr"), Frame(number=2, color=torch.from_numpy(d["color"])))
    # each clause of the README's table (a phrase of its row) and a command that hits it
    cases = {
        0: [("success", ("interpolate", inp, tmp_path / "ok", *RUN)),
            ("success", ("info", inp)), ("success", ("pipelines",))],
        1: [("non-EXR file", ("info", bad)), ("empty folder", ("info", tmp_path / "empty")),
            ("gaps", ("info", gap)), ("missing channels", ("info", ychan)),
            ("frames of different sizes", ("info", sizes)),
            ("not a folder", ("interpolate", tmp_path / "afile", tmp_path / "o1", *RUN))],
        2: [("unknown pipeline", ("interpolate", inp, tmp_path / "o2", "--pipeline", "nope")),
            ("bad option", ("interpolate", inp, tmp_path / "o2", "--bogus")),
            ("out of its range", ("interpolate", inp, tmp_path / "o2", "--factor", "0")),
            ("--set", ("interpolate", inp, tmp_path / "o2", "--set", "splat.x=1")),
            ("stage", ("describe", "no-such-stage")),
            ("--numbering input", ("interpolate", inp, tmp_path / "o2", "--factor", "4",
                                   "--numbering", "input"))],
        3: [("input folder", ("interpolate", inp, inp, *RUN)),
            ("refusing to overwrite", ("interpolate", inp, existing, *RUN)),
            ("is a file", ("interpolate", inp, tmp_path / "afile", *RUN)),
            ("unwritable folder", ("interpolate", inp, tmp_path / "afile" / "sub", *RUN)),
            ("is a file", ("convert", inp, tmp_path / "afile")),
            ("--report", ("eval", pair, "--pipeline", "repeat", "--report",
                          tmp_path / "afile")),
            ("--json", ("interpolate", inp, tmp_path / "o3", "--json", tmp_path, *RUN))],
    }
    for code, runs in cases.items():
        for clause, args in runs:
            assert clause in table[code], (code, clause)
            got, _, err = fgen(capsys, *args)
            assert got == code, (args, err)
            if code:
                assert len(err.strip().splitlines()) == 1, (args, err)


# ------------------------------------------------------------------- 4. eval --frames


def test_eval_frames_on_an_input_gt_pair(pair, tmp_path, capsys):
    js = tmp_path / "e.json"
    for rng in ("2-6", "2-6x2"):
        code, _, err = fgen(capsys, "eval", pair, "--pipeline", "blend", "--frames", rng,
                            "--json", js, "--backend", "torch", "--no-progress",
                            "--no-hdr-flip")
        assert code == 0, err
        r = json.loads(js.read_text())
        assert r["inputs"] == [2, 4, 6] and r["targets"] == [3, 5]
    code, _, err = fgen(capsys, "eval", pair, "--pipeline", "blend", "--frames", "2-6",
                        "--mode", "extrap", "--json", js, "--backend", "torch",
                        "--no-progress", "--no-hdr-flip", "--pipeline", "repeat")
    assert code == 0, err
    assert json.loads(js.read_text())["targets"] == [3, 5, 7]


# ------------------------------------------------------------------- 6. help, plan, logs


def test_help_reads_like_a_manual(capsys):
    import click

    from fgcli.cli import COMMANDS, cli

    ctx = click.Context(cli)
    for name in COMMANDS:
        cmd = cli.get_command(ctx, name)
        for p in cmd.params:
            if isinstance(p, click.Option):
                assert p.help, f"fgen {name} {p.opts[0]} has no help text"
        code, out, _ = fgen(capsys, name, "--help")
        assert code == 0 and "DESIGN.md" not in out and "%%" not in out
    for name in ("interpolate", "extrapolate", "eval"):
        code, out, _ = fgen(capsys, name, "--help")
        heads = [ln.strip() for ln in out.splitlines() if ln.strip().endswith("options:")]
        assert heads[:4] == ["Pipeline options:", "Input options:", "Output options:",
                             "Execution options:"], heads
        first = out.split("Pipeline options:", 1)[1].strip().splitlines()[0]
        assert first.lstrip().startswith("-p, --pipeline")
    code, out, _ = fgen(capsys, "interpolate", "--help")
    for opt in ("--threads", "--dry-run", "--numbering"):
        assert opt in out


def test_dry_run_prints_the_plan_per_chunk_and_writes_nothing(pair, tmp_path, capsys):
    code, out, err = fgen(capsys, "interpolate", pair / "input", tmp_path / "o", "--factor",
                          "4", "--emit", "all", "--chunk", "2/2", "--dry-run")
    assert code == 0, err
    assert not (tmp_path / "o").exists()
    lines = out.splitlines()
    assert "chunk 2/2: 9 of 17 output frames" in lines[0] and "numbering scaled (x2)" in lines[0]
    assert any(re.match(r"\s+s\.0009\.exr\s+<- input frames 4, 6 \(alpha 1/4; at input "
                        r"frame 4\.5\)", ln) for ln in lines), out
    assert any("s.0012.exr  <- copy of input frame 6" in ln for ln in lines)
    assert any("s.0008.exr  <- copy of input frame 4" in ln for ln in lines)
    assert not any("s.0007.exr" in ln for ln in lines)  # chunk 1's


def test_progress_lines_in_a_log_and_threads(pair, tmp_path, capsys, monkeypatch):
    for k in ("FGEN_COMPUTE_THREADS", "OMP_NUM_THREADS", "NUMBA_NUM_THREADS"):
        monkeypatch.setenv(k, os.environ.get(k, "2"))
    monkeypatch.setenv("FGEN_PROGRESS_SECONDS", "0")
    threads = torch.get_num_threads()
    try:
        code, _, err = fgen(capsys, "interpolate", pair / "input", tmp_path / "o", "--pipeline",
                            "blend", "--backend", "torch", "--threads", "1")
        assert code == 0, err
        assert torch.get_num_threads() == 1 and os.environ["FGEN_COMPUTE_THREADS"] == "1"
    finally:
        torch.set_num_threads(threads)
    logs = [ln for ln in err.splitlines() if re.match(r"fgen: blend interp: \d+/4 frames", ln)]
    assert logs and logs[-1].startswith("fgen: blend interp: 4/4 frames (100%)")
