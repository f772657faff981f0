"""Temporal stability of a sequence of outputs: how much the error changes from one scored
frame to the next once the previous error is carried along the true motion.

A reconstruction that flickers (jittered samples shown raw, history dropped and rebuilt)
can score a good per-frame PSNR; what a viewer sees is its error moving. For consecutive
scored frames m < n (their numbers on the ground truth's timeline), with e = display(out) -
display(gt) (sRGB OETF of clip(x, 0, 1), 3 channels):

    temporal_change = mean over pixels q of mean_c |e_n(q) - e_m(q + D(q))|

D chains the ground truth's vectors from n back to m (frame k's vectors point to k - 1;
where the ground truth has no frame k, the vectors of the source frame that has it, scaled
to one step: linear motion). Pixels whose chained place is off-screen or shows a nearer
surface in frame m (disoccluded: no previous error to compare with) are left out. Lower is
steadier; 0 for a method whose error is carried exactly along the motion.
"""
from __future__ import annotations

import math


class TemporalChange:
    """Accumulates temporal_change over a stream of scored frames (in number order).
    step_frame(k) -> a Frame whose `mv` points from k to k - 1 (and `depth`), or None.
    chains: a dict shared by the accumulators of one evaluation (one per pipeline), so the
    chained motion between two ground-truth frames is computed once."""

    def __init__(self, step_frame, rel_tol: float = 0.05, max_gap: int = 8,
                 chains: dict | None = None):
        self.step_frame, self.rel_tol, self.max_gap = step_frame, rel_tol, max_gap
        self.chains = {} if chains is None else chains
        self.prev = None  # (number, error (3, H, W), gt depth)
        self.total, self.count, self.pairs = 0.0, 0, 0

    def _chain(self, n: int, m: int, gt):
        import torch

        from fgcli.ops import backward_warp, disocclusion_mask, sample_nearest

        if n - m > self.max_gap or gt.mv is None or gt.depth is None:
            return None
        H, W = gt.depth.shape[-2:]
        disp = torch.zeros(2, H, W)
        occluded = torch.zeros(1, H, W, dtype=torch.bool)
        depth_k = gt.depth
        for k in range(n, m, -1):
            fk = gt if k == n else self.step_frame(k)
            if fk is None or fk.mv is None or fk.depth is None or fk.mv.shape[-2:] != (H, W):
                return None
            if k != n:
                step, _ = backward_warp(fk.mv, disp, mode="bilinear")
                depth_k, _ = sample_nearest(fk.depth, disp)
            else:
                step = fk.mv
            disp = disp + torch.nan_to_num(step, nan=0.0)
            prev = self.step_frame(k - 1)
            if prev is None or prev.depth is None:
                return None
            occluded |= disocclusion_mask(depth_k, disp, prev.depth, self.rel_tol)
        return disp, ~occluded

    def add(self, n: int, out, gt_color, gt) -> None:
        from fgcli.ops import backward_warp
        from fgcli.ops.color import srgb_oetf

        err = srgb_oetf(out.detach().float().cpu()) - srgb_oetf(gt_color.detach().float().cpu())
        if self.prev is not None and self.prev[1].shape == err.shape:
            m, perr = self.prev
            if (n, m) not in self.chains:
                while len(self.chains) > 4:  # (frames come in order: the last few pairs)
                    self.chains.pop(next(iter(self.chains)))
                self.chains[(n, m)] = self._chain(n, m, gt)
            got = self.chains[(n, m)]
            if got is not None:
                disp, ok = got
                warped, inside = backward_warp(perr, disp, mode="bilinear")
                valid = (ok & inside)[0]
                k = int(valid.sum())
                if k:
                    self.total += float((err - warped).abs().mean(0)[valid].sum())
                    self.count += k
                    self.pairs += 1
        self.prev = (n, err)

    def result(self) -> float:
        return self.total / self.count if self.count else float("nan")


def step_frames_of(src):
    """step_frame for an evaluation source: the ground truth's frame k where it has one,
    else the input frame k with its vectors scaled to one step (they span the input
    interval: linear motion)."""
    def step(k):
        f = src.fine_mv(k)
        if f is not None:
            return f
        ins = list(getattr(src, "inputs", ()))
        if k in ins:
            i = ins.index(k)
            if i == 0:
                return None
            f = src.input(k)
            span = k - ins[i - 1]
            if f.mv is None or span <= 0 or not math.isfinite(span):
                return None
            return f.replace(mv=f.mv / float(span))
        return None
    return step
