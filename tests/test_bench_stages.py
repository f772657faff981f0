"""benchmarks/stages.py: the sequence mode (a RunState carried over consecutive frames)."""
import json
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def test_stages_benchmark_sequence_mode(tmp_path):
    out = tmp_path / "b.json"
    r = subprocess.run([sys.executable, os.path.join(ROOT, "benchmarks", "stages.py"),
                        "--size", "64x36", "--pipelines", "gffe-extrap,mob-fgsr", "--backends",
                        "torch", "--repeat", "2", "--sequence", "--json", str(out)],
                       capture_output=True, text=True, cwd=ROOT, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "a sequence (state carried)" in r.stdout
    j = json.loads(out.read_text())
    assert j["sequence"] is True
    g = j["pipelines"]["gffe-extrap"]["extrap"]
    assert g["ms_per_frame"] > 0
    # the frames move (history tracked and layers collected every frame), mob-fgsr both modes
    assert g["stages"]["history"] > 0 and g["stages"]["background"] > 0
    assert set(j["pipelines"]["mob-fgsr"]) == {"interp", "extrap"}


def test_stages_benchmark_on_footage(tmp_path):
    """--input: the frames of an EXR sequence (here the bundled orbit render, with its
    cameras.json) instead of the rendered scene; its size, not --size."""
    out = tmp_path / "b.json"
    r = subprocess.run([sys.executable, os.path.join(ROOT, "benchmarks", "stages.py"),
                        "--input", os.path.join(ROOT, "sample_data", "orbit", "input"),
                        "--size", "64x36", "--pipelines", "gffe-extrap,mob-fgsr",
                        "--backends", "torch", "--repeat", "2", "--json", str(out)],
                       capture_output=True, text=True, cwd=ROOT, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    j = json.loads(out.read_text())
    assert j["size"] == [256, 144] and "orbit/input" in j["frames"]
    assert j["pipelines"]["gffe-extrap"]["extrap"]["ms_per_frame"] > 0  # (its cameras read)
    assert set(j["pipelines"]["mob-fgsr"]) == {"interp", "extrap"}
