"""The claims of docs/results.md, checked on the bundled scenes with `fgen eval` itself:
for interpolation mob-fgsr beats mv-warp and mv-warp beats blend (PSNR and LDR-FLIP) on the
scenes with motion; for extrapolation mob-fgsr beats repeat and mv-warp. The lighting-only
scene (`shadows`) is where every MV method reduces to a blend (docs/design.md section 4)."""
from __future__ import annotations

import json
import os

import pytest
from click.testing import CliRunner

from fgcli.cli import cli

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MOVING = ["orbit", "blade", "throw"]


def _eval(tmp_path, scene, mode, pipes):
    js = tmp_path / f"{scene}-{mode}.json"
    r = CliRunner().invoke(cli, ["eval", os.path.join(ROOT, "sample_data", scene), "--pipeline",
                                 pipes, "--mode", mode, "--json", str(js), "--no-progress",
                                 "--no-hdr-flip"])
    assert r.exit_code == 0, r.output
    return json.loads(js.read_text())["pipelines"]


@pytest.mark.parametrize("scene", MOVING)
def test_interpolation_ranking(tmp_path, scene):
    res = _eval(tmp_path, scene, "interp", "mob-fgsr,mv-warp,blend")
    assert res["mob-fgsr"]["psnr"] > res["mv-warp"]["psnr"] > res["blend"]["psnr"]
    assert res["mob-fgsr"]["flip"] < res["mv-warp"]["flip"] < res["blend"]["flip"]
    # and where it matters most: the pixels disoccluded in the ground truth
    assert res["mob-fgsr"]["psnr_disoccluded"] > res["mv-warp"]["psnr_disoccluded"]


@pytest.mark.parametrize("scene", MOVING)
def test_extrapolation_ranking(tmp_path, scene):
    res = _eval(tmp_path, scene, "extrap", "mob-fgsr,mv-warp,repeat")
    for base in ("mv-warp", "repeat"):
        assert res["mob-fgsr"]["psnr"] > res[base]["psnr"]
        assert res["mob-fgsr"]["flip"] < res[base]["flip"]


def test_lighting_only_scene_skips_motion_stages(tmp_path):
    res = _eval(tmp_path, "shadows", "interp", "mob-fgsr,blend")
    # no motion anywhere: splat/gap fill/warp are skipped on every frame, and the time
    # they would have cost is measured and reported
    assert res["mob-fgsr"]["skipped_stage_runs"] >= 3 * 16
    assert res["mob-fgsr"]["ms_saved_per_frame"] > 0
    assert "splat" not in res["mob-fgsr"]["stages"]


@pytest.mark.parametrize("scene", MOVING)
def test_mv_interp_network_beats_its_warp_and_mob_fgsr(tmp_path, scene):
    """The shipped mv-interp weights (trained on random scenes only) against their own
    guiding-flow warp and mob-fgsr, PSNR overall (docs/results.md: margins 1.4-3.9 dB, far
    above float differences between CPUs)."""
    res = _eval(tmp_path, scene, "interp", "mv-interp,mv-interp:network=off,mob-fgsr")
    assert res["mv-interp"]["psnr"] > res["mv-interp:network=off"]["psnr"] + 1.0
    assert res["mv-interp"]["psnr"] > res["mob-fgsr"]["psnr"] + 0.5
    # and on the disoccluded pixels (margins 0.44 blade, 1.45 throw, 2.50 orbit dB; the
    # disoccluded set is a few hundred pixels per frame; float differences between CPUs'
    # kernels move it by thousandths of a dB, far below the 0.2 dB asked)
    for other in ("mv-interp:network=off", "mob-fgsr"):
        assert res["mv-interp"]["psnr_disoccluded"] > res[other]["psnr_disoccluded"] + 0.2


def test_mv_interp_moves_the_shading_on_the_moving_light_scene(tmp_path):
    """`shadows` (only the light moves, every vector is zero): the network moves the
    shadows the vectors miss, and the static cross-fade keeps the pixels whose colour
    hardly changes exact (docs/results.md: 53.78 dB against 52.87 for mob-fgsr and the
    guided warp, 53.32 without the cross-fade; margins far above float noise)."""
    res = _eval(tmp_path, "shadows", "interp",
                "mv-interp,mv-interp:network=off,mob-fgsr,mv-interp:static_crossfade=false")
    for other, margin in (("mv-interp:network=off", 0.4), ("mob-fgsr", 0.4),
                          ("mv-interp:static_crossfade=false", 0.2)):
        assert res["mv-interp"]["psnr"] > res[other]["psnr"] + margin, other


@pytest.mark.parametrize("scene", MOVING)
def test_gffe_beats_mob_fgsr_and_mv_warp_extrapolating(tmp_path, scene):
    """Issue 11's bar (docs/results.md, stop 19): on every bundled scene with camera motion
    or moving objects gffe-extrap beats mob-fgsr and mv-warp extrapolation in PSNR overall
    and on disoccluded pixels. Measured: throw 35.63 / 28.21 against mob-fgsr's 35.62 /
    27.28, blade 33.37 / 23.70 against 33.21 / 23.66, orbit 35.85 / 26.76 against 35.79 /
    26.35. The thinnest margins (throw overall +0.016 dB, blade disoccluded +0.044 dB)
    are still 100x the float differences between CPUs (~1e-4 dB); the test asks for 0.005.
    Ablations, each worse on the scene made for it: without Mob-FGSR's hole rule
    (vector_rule=off) on throw and blade; without the background layers on throw; the
    paper's quadratic motion on throw (35.06; the window's ablation: tests/test_gffe.py)."""
    js = tmp_path / f"{scene}-gffe.json"
    variants = ["--variant", "gffe-extrap:vector_rule=off", "--variant",
                "gffe-extrap:background=off"] if scene != "orbit" else []
    if scene == "throw":
        variants += ["--variant", "gffe-extrap:motion=quadratic"]
    r = CliRunner().invoke(cli, ["eval", os.path.join(ROOT, "sample_data", scene),
                                 "--pipeline", "gffe-extrap,mob-fgsr,mv-warp", *variants,
                                 "--mode", "extrap", "--json", str(js), "--no-progress",
                                 "--no-hdr-flip"])
    assert r.exit_code == 0, r.output
    res = json.loads(js.read_text())["pipelines"]
    g = res["gffe-extrap"]
    for other in ("mob-fgsr", "mv-warp"):
        o = res[other]
        assert g["psnr"] > o["psnr"] + 0.005, other
        assert g["psnr_disoccluded"] > o["psnr_disoccluded"] + 0.005, other
    if scene == "orbit":
        return
    off = res["gffe-extrap:vector_rule=off"]
    assert g["psnr"] > off["psnr"] and g["psnr_disoccluded"] > off["psnr_disoccluded"] + 1
    if scene == "throw":
        bg = res["gffe-extrap:background=off"]
        assert g["psnr"] > bg["psnr"] + 0.05 and g["psnr_disoccluded"] > bg["psnr_disoccluded"] + 1
        assert g["psnr"] > res["gffe-extrap:motion=quadratic"]["psnr"] + 0.3
