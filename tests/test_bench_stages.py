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
