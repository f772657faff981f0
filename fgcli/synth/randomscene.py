"""Random but valid scenes, for property tests and for making training data on the fly."""
from __future__ import annotations

import numpy as np

from fgcli.synth.scene import EFFECTS

# effects a random scene may switch on by itself (overlay effects only when asked for)
RANDOM_EFFECTS = ("shadows", "specular", "reflection", "translucency", "texture_animation")


def _r(x, nd=4):
    if isinstance(x, (list, tuple, np.ndarray)):
        return [_r(v, nd) for v in x]
    return round(float(x), nd)


def _color(rng, lo=0.15, hi=0.8):
    return _r(rng.uniform(lo, hi, 3))


def _texture(rng, scroll: bool) -> dict:
    kind = rng.choice(["solid", "checker", "stripes", "noise", "bricks"])
    tex = {"type": str(kind), "colors": [_color(rng), _color(rng)],
           "scale": _r(rng.uniform(0.15, 0.8))}
    if kind == "stripes":
        tex["angle"] = _r(rng.uniform(0, 180))
    if kind == "noise":
        tex["seed"] = int(rng.integers(0, 1000))
    if scroll:
        tex["scroll"] = _r(rng.uniform(-0.6, 0.6, 2))
    return tex


def _motion(rng, pos) -> dict:
    kind = rng.choice(["static", "linear", "ballistic", "rotate", "keyframes"],
                      p=[0.2, 0.3, 0.15, 0.15, 0.2])
    if kind == "static":
        return {"type": "static"}
    if kind == "linear":
        v = rng.uniform(-2.0, 2.0, 3)
        v[1] *= 0.3
        return {"type": "linear", "velocity": _r(v)}
    if kind == "ballistic":
        return {"type": "ballistic", "velocity": _r([rng.uniform(-2, 2), rng.uniform(2, 5),
                                                     rng.uniform(-1, 1)])}
    if kind == "rotate":
        return {"type": "rotate", "axis": [0.0, 1.0, 0.0], "speed": _r(rng.uniform(-90, 90)),
                "pivot": [0.0, 0.0, 0.0]}
    keys = []
    p = np.asarray(pos, float)
    for k in range(3):
        keys.append({"time": _r(k * 0.5), "position": _r(p + rng.uniform(-1, 1, 3) * [1, 0.2, 1]),
                     "rotation": _r(rng.uniform(-40, 40, 3))})
    return {"type": "keyframes", "smooth": bool(rng.random() < 0.5), "keys": keys}


def random_scene(seed: int, size=(128, 72), frames: int = 9, fps: float = 24.0,
                 effects: list[str] | None = None, spp: int = 2) -> dict:
    """A random scene dict for load_scene: a textured ground, 3-6 moving objects of every
    shape, a camera preset, one or two lights (possibly moving).

    effects None: a random subset of RANDOM_EFFECTS; a list: exactly those effects (any of
    EFFECTS). Same seed, same scene.
    """
    rng = np.random.default_rng(seed)
    if effects is None:
        effects = [e for e in RANDOM_EFFECTS if rng.random() < 0.5]
    else:
        bad = [e for e in effects if e not in EFFECTS]
        if bad:
            raise ValueError(f"unknown effects {bad}")
    reflect = "reflection" in effects
    transl = "translucency" in effects
    anim = "texture_animation" in effects
    objects = [{"name": "ground", "type": "plane",
                "texture": _texture(rng, anim and rng.random() < 0.3),
                "roughness": _r(rng.uniform(0.4, 1.0)), "specular": 0.1}]
    if reflect and rng.random() < 0.5:
        objects[0]["mirror"] = _r(rng.uniform(0.1, 0.4))
    n = int(rng.integers(3, 7))
    for i in range(n):
        shape = str(rng.choice(["box", "sphere", "cylinder", "blade"]))
        pos = [rng.uniform(-2.5, 2.5), 0.0, rng.uniform(-2.5, 1.5)]
        ob = {"name": f"o{i}", "type": shape}
        if shape == "box":
            s = rng.uniform(0.3, 1.2, 3)
            ob["size"] = _r(s)
            pos[1] = s[1] / 2 + rng.uniform(0, 0.5)
        elif shape == "sphere":
            r = rng.uniform(0.2, 0.7)
            ob["radius"] = _r(r)
            pos[1] = r + rng.uniform(0, 0.8)
        elif shape == "cylinder":
            ob["radius"] = _r(rng.uniform(0.05, 0.3))
            h = rng.uniform(0.5, 2.0)
            ob["height"] = _r(h)
            pos[1] = h / 2
        else:
            ob["size"] = _r([rng.uniform(1.0, 2.0), rng.uniform(0.06, 0.15), 0.03])
            pos[1] = rng.uniform(0.8, 1.6)
            ob["spin"] = {"axis": [0.0, 0.0, 1.0], "speed": _r(rng.uniform(-600, 600))}
        ob["position"] = _r(pos)
        ob["rotation"] = _r([0.0, rng.uniform(0, 90), 0.0])
        ob["texture"] = _texture(rng, anim and rng.random() < 0.5)
        ob["roughness"] = _r(rng.uniform(0.1, 0.9))
        ob["motion"] = _motion(rng, pos)
        if shape != "blade" and rng.random() < 0.25:
            ob["spin"] = {"axis": _r(rng.uniform(-1, 1, 3) + [0, 1.5, 0]),
                          "speed": _r(rng.uniform(-180, 180))}
        if reflect and rng.random() < 0.4:
            ob["mirror"] = _r(rng.uniform(0.3, 0.9))
        if transl and rng.random() < 0.35:
            ob["opacity"] = _r(rng.uniform(0.25, 0.7))
        objects.append(ob)
    kind = str(rng.choice(["static", "orbit", "pan", "dolly", "keyframes"]))
    dist = rng.uniform(5.0, 7.5)
    height = rng.uniform(1.0, 3.0)
    ang = rng.uniform(-40, 40)
    pos = [dist * np.sin(np.radians(ang)), height, dist * np.cos(np.radians(ang))]
    target = [0.0, 0.6, 0.0]
    if kind == "static":
        cam = {"type": "static", "position": _r(pos), "target": target}
    elif kind == "orbit":
        cam = {"type": "orbit", "center": target, "radius": _r(dist), "height": _r(height),
               "angle": _r(ang), "speed": _r(rng.uniform(-40, 40))}
    elif kind == "pan":
        # yaw = ang faces the origin at s = 0
        cam = {"type": "pan", "position": _r(pos), "yaw": _r(ang),
               "speed": _r(rng.uniform(-25, 25)),
               "pitch": _r(-np.degrees(np.arctan2(height - 0.6, dist)))}
    elif kind == "dolly":
        cam = {"type": "dolly", "position": _r(pos), "target": target,
               "velocity": _r([rng.uniform(-1.5, 1.5), 0.0, rng.uniform(-1.5, 0.5)])}
    else:
        p2 = np.asarray(pos) + rng.uniform(-1.5, 1.5, 3) * [1, 0.3, 0.5]
        cam = {"type": "keyframes", "keys": [
            {"time": 0.0, "position": _r(pos), "target": target},
            {"time": 1.0, "position": _r(p2),
             "target": _r(np.asarray(target) + rng.uniform(-0.5, 0.5, 3))}]}
    cam["fov"] = _r(rng.uniform(40, 60))
    lights = [{"type": "directional",
               "direction": _r([rng.uniform(-1, 1), -1.0, rng.uniform(-1, 1)]),
               "intensity": _r(rng.uniform(0.9, 1.5))}]
    if rng.random() < 0.4:
        lights[0]["motion"] = {"type": "rotate", "axis": [0.0, 1.0, 0.0],
                               "speed": _r(rng.uniform(-60, 60))}
    if rng.random() < 0.5:
        lp = [rng.uniform(-3, 3), rng.uniform(1.5, 3.5), rng.uniform(-3, 3)]
        pl = {"type": "point", "position": _r(lp), "intensity": _r(rng.uniform(2, 8)),
              "color": _color(rng, 0.6, 1.0)}
        if rng.random() < 0.5:
            pl["motion"] = {"type": "linear", "velocity": _r(rng.uniform(-1.5, 1.5, 3) * [1, 0, 1])}
        lights.append(pl)
    return {"name": f"random{seed}", "size": [int(size[0]), int(size[1])], "fps": float(fps),
            "frames": int(frames), "spp": int(spp), "seed": int(seed), "effects": list(effects),
            "camera": cam, "lights": lights, "objects": objects}
