"""Training task of the mv-interp network (for fgcli.nets.train): random 128x128 crops of
random-scene samples (fgcli.nets.data), random time tau in {0.25, 0.5, 0.75}, random flips
and time reversal;
Charbonnier + census losses on the tone-mapped frame (weights 1 and 1, as the paper);
validation PSNR on held-out random scenes, whole frames, against the network-off warp."""
from __future__ import annotations

import glob
import os

import numpy as np
import torch


def load_samples(folder: str, limit: int | None = None) -> list[dict]:
    files = sorted(glob.glob(os.path.join(folder, "s*.npz")))
    if limit:
        files = files[:limit]
    if not files:
        raise FileNotFoundError(f"no training samples (s*.npz) in {folder}")
    out = []
    for f in files:
        with np.load(f) as z:
            out.append({k: z[k] for k in ("c0", "c1", "gt", "g0", "g1", "cue", "taus",
                                               "moving_light")})
    return out


def _psnr(a: torch.Tensor, b: torch.Tensor) -> float:
    from fgcli.ops.color import srgb_oetf

    mse = float(((srgb_oetf(a.clamp(0, 1)) - srgb_oetf(b.clamp(0, 1))) ** 2).mean())
    return 10.0 * np.log10(1.0 / max(mse, 1e-10))


# |depth-ratio cue| from which the guided samples count as different surfaces: the cue is
# log(z0 / z1) / 2 clamped to +-1, so 0.1 is a 22 % depth difference
OCCLUSION_CUE = 0.1


class MVInterpTask:
    name = "mv-interp"
    loss_terms = ("charbonnier", "census")
    val_terms = ("psnr_net", "psnr_guide", "psnr_net_light", "psnr_guide_light")

    def __init__(self, train_dir: str, val_dir: str, widths=None, patch: int = 128,
                 batch: int = 8, limit: int | None = None, val_limit: int | None = None,
                 seed: int = 0, guides: bool = True, extra_dirs=(), hole_weight: float = 0.0,
                 occlusion_weight: float = 0.0):
        from fgcli.nets.mvinterp import DEFAULT_WIDTHS, MVInterpNet

        self.widths = tuple(widths or DEFAULT_WIDTHS)
        # guides False: the paper's ablation without guiding flows (plain IFRNet-style):
        # zero guides and cue channels in training, validation and at run time
        self.guides = bool(guides)
        self.patch, self.batch_size = int(patch), int(batch)
        # extra Charbonnier weight on guide-hole pixels (no frame-1 surface splats there:
        # the guiding flows carry no information and the network alone must choose the
        # frame); rare pixels, so a plain mean barely sees them
        self.hole_weight = float(hole_weight)
        # extra Charbonnier weight where the two guided samples are different surfaces
        # (|depth-ratio cue| >= OCCLUSION_CUE: one of them is an occluder, so the merge mask
        # alone decides which frame is right there; Mob-FGSR's Eq. 1 takes one frame exactly)
        self.occlusion_weight = float(occlusion_weight)
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(seed)  # the initial weights depend on the seed only
            self.model = MVInterpNet(self.widths)
        self.train = load_samples(train_dir, limit)
        self.extra = [os.path.basename(os.path.normpath(d)) for d in extra_dirs]
        for d in extra_dirs:
            self.train += load_samples(d)
        self.val = load_samples(val_dir, val_limit)
        self.n_train = len(self.train)

    def config(self) -> dict:
        return {"widths": list(self.widths), "patch": self.patch, "batch": self.batch_size,
                "samples": self.n_train, "augment": "flip,reverse",
                **({} if self.guides else {"guides": False}),
                **({"hole_weight": self.hole_weight} if self.hole_weight else {}),
                **({"occlusion_weight": self.occlusion_weight} if self.occlusion_weight
                   else {}),
                **({"extra": self.extra} if self.extra else {})}

    def batch(self, seed: int, step: int) -> dict:
        rng = np.random.default_rng([seed, step, 11])
        P = self.patch
        cols = {k: [] for k in ("c0", "c1", "g0", "g1", "cue", "gt", "t")}
        for _ in range(self.batch_size):
            s = self.train[int(rng.integers(self.n_train))]
            k = int(rng.integers(len(s["taus"])))
            H, W = s["c0"].shape[-2:]
            y = int(rng.integers(0, H - P + 1)) if H > P else 0
            x = int(rng.integers(0, W - P + 1)) if W > P else 0
            sl = (Ellipsis, slice(y, y + P), slice(x, x + P))
            c0 = torch.from_numpy(s["c0"][sl].astype(np.float32))
            c1 = torch.from_numpy(s["c1"][sl].astype(np.float32))
            gt = torch.from_numpy(s["gt"][k][sl].astype(np.float32))
            g0 = torch.from_numpy(s["g0"][k][sl].copy())
            g1 = torch.from_numpy(s["g1"][k][sl].copy())
            cue = torch.from_numpy(s["cue"][k][sl].astype(np.float32))
            if rng.random() < 0.5:  # horizontal flip: x components change sign
                c0, c1, gt, g0, g1, cue = (v.flip(-1) for v in (c0, c1, gt, g0, g1, cue))
                g0[0].neg_()
                g1[0].neg_()
            t = float(s["taus"][k])
            if rng.random() < 0.5:
                # time reversal: the same two frames the other way round, at 1 - tau; the
                # guiding flows swap roles, the depth ratio changes sign (the hole channel
                # then marks surfaces the new frame 0 misses: the network has to read the
                # depth cue and the images, not a prior for one frame)
                c0, c1, g0, g1 = c1, c0, g1, g0
                cue = cue.clone()
                cue[0].neg_()
                t = 1.0 - t
            if rng.random() < 0.5:  # vertical flip
                c0, c1, gt, g0, g1, cue = (v.flip(-2) for v in (c0, c1, gt, g0, g1, cue))
                g0[1].neg_()
                g1[1].neg_()
            for name, v in (("c0", c0), ("c1", c1), ("gt", gt), ("g0", g0), ("g1", g1),
                            ("cue", cue)):
                cols[name].append(v)
            cols["t"].append(torch.full((1, 1, 1), t))
        out = {k: torch.stack(v) for k, v in cols.items()}
        if not self.guides:
            for k in ("g0", "g1", "cue"):
                out[k] = torch.zeros_like(out[k])
        return out

    def loss(self, model, b) -> dict:
        from fgcli.nets.blocks import census, charbonnier
        from fgcli.ops.mvinterp import tonemap

        out = model(b["c0"], b["c1"], b["g0"], b["g1"], b["cue"], b["t"])[0]
        y, g = tonemap(out), tonemap(b["gt"])
        if self.hole_weight or self.occlusion_weight:
            w = (1.0 + self.hole_weight * (b["cue"][:, 1:2] > 0.5).to(y.dtype)
                 + self.occlusion_weight * (b["cue"][:, 0:1].abs() >= OCCLUSION_CUE).to(y.dtype))
            ch = (torch.sqrt((y - g) ** 2 + 1e-6) * w).sum() / (w.sum() * y.shape[1])
            return {"charbonnier": ch, "census": census(y, g)}
        return {"charbonnier": charbonnier(y, g), "census": census(y, g)}

    def validate(self, model, dev) -> dict:
        from fgcli.ops.mvinterp import guide_warp

        net, guide, net_l, guide_l = [], [], [], []
        for s in self.val:
            c0 = torch.from_numpy(s["c0"].astype(np.float32))
            c1 = torch.from_numpy(s["c1"].astype(np.float32))
            for k, tau in enumerate(s["taus"]):
                g0, g1 = torch.from_numpy(s["g0"][k]), torch.from_numpy(s["g1"][k])
                cue = torch.from_numpy(s["cue"][k].astype(np.float32))
                if not self.guides:
                    g0, g1, cue = (torch.zeros_like(v) for v in (g0, g1, cue))
                gt = torch.from_numpy(s["gt"][k].astype(np.float32))
                out = model(c0[None].to(dev), c1[None].to(dev), g0[None].to(dev),
                            g1[None].to(dev), cue[None].to(dev),
                            torch.full((1, 1, 1, 1), float(tau),
                                                         device=dev))[0][0].cpu()
                a, b = _psnr(out, gt), _psnr(guide_warp(c0, c1, g0, g1, float(tau)), gt)
                net.append(a)
                guide.append(b)
                if bool(s["moving_light"]):
                    net_l.append(a)
                    guide_l.append(b)
        return {"psnr_net": float(np.mean(net)), "psnr_guide": float(np.mean(guide)),
                "psnr_net_light": float(np.mean(net_l)) if net_l else float("nan"),
                "psnr_guide_light": float(np.mean(guide_l)) if guide_l else float("nan")}
