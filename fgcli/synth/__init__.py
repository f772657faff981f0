"""Procedural scene renderer: exact color, depth, motion vectors and G-buffers at any time.

    scene = load_scene("sample_data/scenes/orbit.toml", size=(96, 64))
    f = render(scene, t=3.5, prev_t=3.0)          # Frame; scene.stats counts the work
    render_sequence(scene, "out/input", gt_dir="out/gt", gt_factor=2)
    scene = load_scene(random_scene(seed=7))       # random valid scene, for tests/training

See docs/synth.md for the scene format and the frame-number timeline. Importing this
package imports torch.
"""
from fgcli.synth.preview import contact_sheet, write_contact_sheet
from fgcli.synth.randomscene import random_scene
from fgcli.synth.tracer import FrameCamera, frame_camera, render
from fgcli.synth.scene import EFFECTS, Scene, load_scene
from fgcli.synth.sequence import render_sequence, schedule

__all__ = ["EFFECTS", "FrameCamera", "Scene", "contact_sheet", "frame_camera", "load_scene",
           "random_scene", "render", "render_sequence", "schedule", "write_contact_sheet"]
