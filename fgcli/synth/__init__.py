"""Procedural scene renderer: exact color, depth, motion vectors and G-buffers at any time.

    scene = load_scene("sample_data/scenes/orbit.toml", size=(96, 64))
    f = render(scene, t=3.5, prev_t=3.0)          # Frame; scene.stats counts the work
    render_sequence(scene, "out/input", gt_dir="out/gt", gt_factor=2)

See docs/synth.md for the scene format and the frame-number timeline.
"""
from fgcli.synth.render import frame_camera, render
from fgcli.synth.scene import EFFECTS, Scene, load_scene

__all__ = ["EFFECTS", "Scene", "frame_camera", "load_scene", "render"]
