"""Inference of the shipped networks: onnxruntime on CPU (the default), torch on CUDA (or
on CPU when asked). Weights load from the installed package (fgcli/nets/weights/), never
from the network. Sessions and modules are cached per process."""
from __future__ import annotations

import functools
import os

import numpy as np
import torch

from fgcli.errors import UsageError
from fgcli.nets.export import WEIGHTS_DIR

BACKENDS = ("auto", "onnx", "torch")


def weights_path(name: str, ext: str, folder: str | None = None) -> str:
    p = os.path.join(folder or WEIGHTS_DIR, f"{name}.{ext}")
    if not os.path.exists(p):
        raise UsageError(f"weights of network '{name}' not found: {p} (train them with "
                         f"`fgen train {name} ... --export {folder or WEIGHTS_DIR}`)")
    return p


def resolve(backend: str, device) -> str:
    if backend not in BACKENDS:
        raise UsageError(f"network backend must be one of {', '.join(BACKENDS)}")
    if backend == "auto":
        return "torch" if torch.device(device).type == "cuda" else "onnx"
    return backend


@functools.lru_cache(maxsize=8)
def onnx_session(path: str, threads: int = 0):
    import onnxruntime as ort

    so = ort.SessionOptions()
    so.intra_op_num_threads = threads or min(os.cpu_count() or 1, 16)
    so.inter_op_num_threads = 1
    so.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    return ort.InferenceSession(path, so, providers=["CPUExecutionProvider"])


@functools.lru_cache(maxsize=8)
def _torch_model(path: str, device: str):
    from fgcli.nets.mvinterp import MVInterpNet

    ck = torch.load(path, map_location="cpu", weights_only=True)
    net = MVInterpNet(tuple(ck["info"]["widths"]))
    net.load_state_dict(ck["model"])
    return net.eval().to(device)


def run_mvinterp(c0, c1, g0, g1, cue, alpha: float, backend: str = "auto",
                 folder: str | None = None, name: str = "mv-interp"):
    """Run the mv-interp network on (B, C, H, W) tensors whose H, W are multiples of 16.
    Returns color (B, 3, H, W), f0, f1 (B, 2, H, W), mask (B, 1, H, W) on c0's device."""
    dev = c0.device
    b = resolve(backend, dev)
    t = torch.full((c0.shape[0], 1, 1, 1), float(alpha), dtype=torch.float32, device=dev)
    if b == "torch":
        net = _torch_model(weights_path(name, "pt", folder), str(dev))
        with torch.inference_mode():
            return net(c0, c1, g0, g1, cue, t)
    from fgcli.nets.blocks import warp
    from fgcli.nets.mvinterp import synthesize
    from fgcli.ops.mvinterp import tonemap

    sess = onnx_session(weights_path(name, "onnx", folder))
    with torch.inference_mode():
        x0, x1 = tonemap(c0), tonemap(c1)
        w0, w1 = warp(x0, g0), warp(x1, g1)
        feed = {k: np.ascontiguousarray(v.detach().cpu().numpy(), dtype=np.float32)
                for k, v in (("x0", x0), ("x1", x1), ("w0", w0), ("w1", w1), ("g0", g0),
                             ("g1", g1), ("cue", cue), ("t", t))}
        f0, f1, M, R = (torch.from_numpy(o).to(dev)
                        for o in sess.run(["f0", "f1", "mask", "residual"], feed))
        return synthesize(c0, c1, f0, f1, M, R), f0, f1, M
