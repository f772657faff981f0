"""Export trained weights for shipping: an ONNX graph of the network core (onnxruntime, the
CPU default; the full-resolution warps and Eq. 5 around it run as torch ops) and the torch
state dict (the CUDA path), both in the package (fgcli/nets/weights/)."""
from __future__ import annotations

import os

import torch

WEIGHTS_DIR = os.path.join(os.path.dirname(__file__), "weights")
OPSET = 17


def export_mvinterp(checkpoint: str, dest: str = WEIGHTS_DIR, name: str = "mv-interp") -> dict:
    """Write <dest>/<name>.onnx and <dest>/<name>.pt (state dict + widths, float32) from a
    training checkpoint (best.pt or last.pt), or from shipped weights (a <name>.pt written
    here: re-exports its ONNX graph). Returns the paths and sizes.

    The ONNX graph is the network's core in its export form: the feature warps as gathers
    and the 4x4 transposed convolutions as 3x3 convolutions + DepthToSpace (see
    fgcli.nets.blocks), the same function to float32 rounding, ~1.4x faster in
    onnxruntime at 1080p than the plain trace (GridSample, ConvTranspose)."""
    import warnings

    from fgcli.io.atomic import make_temp, replace
    from fgcli.nets.mvinterp import MVInterpCore, MVInterpNet

    ck = torch.load(checkpoint, map_location="cpu", weights_only=False)
    if "meta" in ck:  # a training checkpoint
        widths = tuple(ck["meta"]["config"]["widths"])
        info = {"widths": list(widths), "step": int(ck["step"]),
                "score": float(ck.get("score", float("nan"))), "task": ck["meta"]["task"]}
    else:  # shipped weights
        info = dict(ck["info"])
        widths = tuple(info["widths"])
    net = MVInterpNet(widths).eval()
    net.load_state_dict(ck["model"])
    os.makedirs(dest, exist_ok=True)
    pt = os.path.join(dest, f"{name}.pt")
    onnx_path = os.path.join(dest, f"{name}.onnx")
    tmp = make_temp(dest, ".pt")
    torch.save({"model": net.state_dict(), "info": info}, tmp)
    replace(tmp, pt)
    x = torch.rand(1, 3, 64, 96)
    g = torch.zeros(1, 2, 64, 96)
    t = torch.full((1, 1, 1, 1), 0.5)
    tmp = make_temp(dest, ".onnx")
    ins = ["x0", "x1", "w0", "w1", "g0", "g1", "cue", "t"]
    outs = ["f0", "f1", "mask", "residual"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(MVInterpCore(net), (x, x, x, x, g, g, g, t), tmp, dynamo=False,
                          opset_version=OPSET, input_names=ins, output_names=outs,
                          dynamic_axes={k: {2: "H", 3: "W"} for k in ins[:-1] + outs})
    replace(tmp, onnx_path)
    return {"onnx": onnx_path, "pt": pt, "onnx_bytes": os.path.getsize(onnx_path),
            "pt_bytes": os.path.getsize(pt), **info}
