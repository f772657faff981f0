"""benchmarks/stages.py: the sequence mode (a RunState carried over consecutive frames);
benchmarks/ab.py: two versions in one process."""
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
    assert j["mv_step"] == 2.0 ** -10  # (the rendered frames' vectors, as fgen synth writes)
    # what the figures depend on besides the code: the CPU and the OpenMP wait settings
    assert j["cpu"] and ("family" in j["cpu"] or not os.path.exists("/proc/cpuinfo"))
    assert j["openmp"]["OMP_WAIT_POLICY"] == os.environ.get("OMP_WAIT_POLICY", "PASSIVE")
    assert set(j["openmp"]) == {"OMP_WAIT_POLICY", "GOMP_SPINCOUNT"}
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


def test_ab_benchmark_runs_two_versions(tmp_path):
    """benchmarks/ab.py exports a revision as the package fgcli_ab (every fgcli import
    renamed) and times both versions in turn: this checkout's HEAD against itself, torch
    ops (no kernels to compile), a tiny frame, both of mob-fgsr's modes."""
    env = dict(os.environ, HOME=str(tmp_path))
    r = subprocess.run([sys.executable, os.path.join(ROOT, "benchmarks", "ab.py"), "HEAD",
                        "--pipelines", "mob-fgsr", "--repeat", "2", "--size", "64x36",
                        "--backend", "torch"],
                       capture_output=True, text=True, cwd=ROOT, timeout=600, env=env)
    assert r.returncode == 0, r.stderr[-2000:]
    rows = [ln for ln in r.stdout.splitlines() if ln.startswith("| mob-fgsr |")]
    assert [ln.split("|")[2].strip() for ln in rows] == ["interp", "extrap"]
    for ln in rows:
        old, new, ratio = (c.strip() for c in ln.split("|")[3:6])
        assert float(old.split()[0]) > 0 and float(new.split()[0]) > 0 and float(ratio) > 0
    base = next((tmp_path / ".cache" / "fgen-ab").iterdir())
    for d, _, files in os.walk(base / "fgcli_ab"):
        for f in files:
            if f.endswith(".py"):
                text = open(os.path.join(d, f), encoding="utf-8").read()
                assert "from fgcli." not in text and "import fgcli\n" not in text, f


def test_benchmark_frames_have_the_written_vectors():
    """The benchmarks' blade frames carry the vectors `fgen synth` writes (rounded to 1/1024
    px: the static set's are exactly zero, as in the shipped sample data), not the tracer's
    unrounded float32 ones, whose ~1e-5 px of noise at every static pixel no file holds and
    which would keep every zero-vector path of the kernels idle."""
    sys.path.insert(0, os.path.join(ROOT, "benchmarks"))
    try:
        from ab import blade_frames
    finally:
        sys.path.pop(0)
    import torch

    from fgcli.synth.sequence import written_vectors

    times = [(3.0, 2.0), (4.0, 3.0)]
    raw = blade_frames("128x72", times, mv_step=0)
    out = blade_frames("128x72", times)
    for r, o in zip(raw, out):
        assert torch.equal(o.color, r.color) and torch.equal(o.depth, r.depth)
        # the upscale (x4, nearest) of the rounded vectors: multiples of 4 / 1024 px
        assert torch.equal(o.mv, written_vectors(r.mv / 4.0) * 4.0)
        static = o.mv.eq(0).all(0)
        assert static.float().mean() > 0.5  # the set and the sky stand still
