"""Training data for the networks, rendered by fgen's own scene renderer from random scenes
(`fgcli.synth.random_scene`): no evaluation scene, no download.

One sample per seed, stored as `<dir>/s<seed>.npz` (written atomically, so an interrupted
generation resumes where it stopped):
  c0, c1: (3, H, W) float16 linear colour of the rendered frames at times i and i + 1;
  taus: (K,) float32 interpolation times; gt: (K, 3, H, W) float16 colour at i + tau;
  g0, g1: (K, 2, H, W) float32 guiding flows at each tau, cue: (K, 2, H, W) float16 cue
  channels (fgcli.ops.mvinterp; frame 0 rendered with its own vectors toward i - 1);
  moving_light: bool, fps: float.
"""
from __future__ import annotations

import os

import numpy as np

TRAIN_SEEDS = (0, 1_000_000)          # training scenes are drawn from here
HELDOUT_SEEDS = (1_000_000, 1_100_000)  # held-out validation scenes
FPS_CHOICES = (12.0, 20.0, 30.0, 45.0)
TAUS = (0.25, 0.5, 0.75)


def sample_path(folder: str, seed: int) -> str:
    return os.path.join(folder, f"s{seed:07d}.npz")


LIGHT_SEEDS = (2_000_000, 2_100_000)  # shading-only scenes (static geometry, moving lights)


def shading_only(spec: dict, rng) -> dict:
    """The same random scene with a static camera and static objects, and moving lights:
    only the shading changes (shadows sweep, highlights slide), every vector is zero."""
    import copy

    spec = copy.deepcopy(spec)
    cam = spec["camera"]
    if cam["type"] != "static":
        pos = cam.get("position") or [cam.get("radius", 6.0) * np.sin(np.radians(cam.get(
            "angle", 0.0))), cam.get("height", 2.0), cam.get("radius", 6.0) * np.cos(
            np.radians(cam.get("angle", 0.0)))]
        if cam["type"] == "keyframes":
            pos = cam["keys"][0]["position"]
        spec["camera"] = {"type": "static", "position": pos, "target": [0.0, 0.6, 0.0],
                          "fov": cam["fov"]}
    for ob in spec["objects"]:
        ob["motion"] = {"type": "static"}
        ob.pop("spin", None)
        if "texture" in ob:
            ob["texture"].pop("scroll", None)
    spec["effects"] = [e for e in spec["effects"] if e != "texture_animation"]
    if "shadows" not in spec["effects"]:
        spec["effects"].append("shadows")
    lights = spec["lights"]
    lights[0]["motion"] = {"type": "rotate", "axis": [0.0, 1.0, 0.0],
                           "speed": float(rng.choice([-1, 1]) * rng.uniform(20, 90))}
    for lt in lights[1:]:
        lt["motion"] = {"type": "linear",
                        "velocity": (rng.uniform(-1.5, 1.5, 3) * [1, 0, 1]).tolist()}
    spec["name"] += "_light"
    return spec


def render_interp_sample(seed: int, size=(256, 144), taus=TAUS, spp: int = 2) -> dict:
    """Render one training sample of random scene `seed` (deterministic in the seed);
    seeds in LIGHT_SEEDS make shading-only scenes (see shading_only)."""
    import torch

    from fgcli.ops.mvinterp import guide_cues, guiding_flows
    from fgcli.synth import load_scene, random_scene, render

    rng = np.random.default_rng([seed, 7])
    fps = float(rng.choice(FPS_CHOICES))
    spec = random_scene(seed, size=size, frames=9, fps=fps, spp=spp)
    if LIGHT_SEEDS[0] <= seed < LIGHT_SEEDS[1]:
        spec = shading_only(spec, rng)
    scene = load_scene(spec)
    i = float(rng.integers(0, 6))
    f0 = render(scene, i, i - 1.0, spp=spp)
    f1 = render(scene, i + 1.0, i, spp=spp)
    gts, g0s, g1s, cues = [], [], [], []
    for tau in taus:
        gts.append(render(scene, i + tau, None, spp=spp).color)
        g0, g1, holes = guiding_flows(f1.depth, f1.mv, tau, f0.mv, f0.depth)
        g0s.append(g0)
        g1s.append(g1)
        cues.append(guide_cues(f0.depth, f1.depth, g0, g1, holes))
    moving = any("motion" in lt for lt in spec["lights"])
    return {"c0": f0.color.numpy().astype(np.float16), "c1": f1.color.numpy().astype(np.float16),
            "taus": np.asarray(taus, np.float32),
            "gt": torch.stack(gts).numpy().astype(np.float16),
            "g0": torch.stack(g0s).numpy().astype(np.float32),
            "g1": torch.stack(g1s).numpy().astype(np.float32),
            "cue": torch.stack(cues).numpy().astype(np.float16),
            "moving_light": np.bool_(moving), "fps": np.float32(fps)}


def make_samples(folder: str, seeds, size=(256, 144), progress: bool = True) -> int:
    """Render every missing sample of `seeds` into folder; returns how many were made."""
    from fgcli.io.atomic import make_temp, replace

    os.makedirs(folder, exist_ok=True)
    todo = [s for s in seeds if not os.path.exists(sample_path(folder, s))]
    bar = None
    if progress and todo:
        from tqdm import tqdm

        bar = tqdm(total=len(todo), unit="scene", desc=f"render {os.path.basename(folder)}")
    for s in todo:
        d = render_interp_sample(s, size=size)
        tmp = make_temp(folder, ".npz")
        try:
            with open(tmp, "wb") as fh:
                np.savez(fh, **d)
            replace(tmp, sample_path(folder, s), sync=False)
        except BaseException:
            if os.path.exists(tmp):
                os.unlink(tmp)
            raise
        if bar is not None:
            bar.update(1)
    if bar is not None:
        bar.close()
    return len(todo)
