"""The training loop every fgen network shares: seeded, resumable, logged.

A *task* supplies the model, a batch for step k (deterministic in (seed, k), so a resumed
run sees exactly the batches an uninterrupted one would), the loss and a validation
score. The loop keeps `<run>/last.pt` (model, optimiser, schedule, step; written
atomically every `ckpt_every` steps and on Ctrl-C), appends to `<run>/loss.csv`
(step, loss terms, learning rate, seconds) and to `<run>/val.csv`, and saves the
best-validating weights to `<run>/best.pt`. Runs on CUDA when available.
"""
from __future__ import annotations

import json
import math
import os
import time

import torch


def _save(obj, path: str) -> None:
    from fgcli.io.atomic import make_temp, replace

    tmp = make_temp(os.path.dirname(path) or ".", ".pt")
    try:
        torch.save(obj, tmp)
        replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def lr_at(step: int, steps: int, lr: float, warmup: int = 200, floor: float = 0.02) -> float:
    """Linear warm-up, then cosine decay to floor·lr."""
    if step < warmup:
        return lr * (step + 1) / warmup
    p = min(1.0, (step - warmup) / max(1, steps - warmup))
    return lr * (floor + (1 - floor) * 0.5 * (1 + math.cos(math.pi * p)))


def train(task, run_dir: str, steps: int, lr: float = 1e-3, seed: int = 0,
          ckpt_every: int = 200, val_every: int = 1000, device: str | None = None,
          progress: bool = True, log=print, init: str | None = None) -> dict:
    """Train task.model for `steps` steps into run_dir, continuing from run_dir/last.pt;
    a new run starts from the weights of checkpoint `init` when given (fine-tuning)."""
    os.makedirs(run_dir, exist_ok=True)
    dev = torch.device(device or ("cuda" if torch.cuda.is_available() else "cpu"))
    torch.manual_seed(seed)
    model = task.model.to(dev)
    opt = torch.optim.AdamW(model.parameters(), lr=lr, weight_decay=1e-4)
    start, best = 0, None
    last = os.path.join(run_dir, "last.pt")
    meta = {"task": task.name, "seed": seed, "steps": steps, "lr": lr,
            "config": task.config(), "init": init}
    if os.path.exists(last):
        ck = torch.load(last, map_location=dev, weights_only=False)
        if ck["meta"]["task"] != task.name or ck["meta"]["config"] != meta["config"]:
            raise ValueError(f"{last}: checkpoint of another task or configuration "
                             f"({ck['meta']['task']}, {ck['meta']['config']})")
        model.load_state_dict(ck["model"])
        opt.load_state_dict(ck["opt"])
        start, best = ck["step"], ck.get("best")
        log(f"resuming {task.name} at step {start} of {steps}")
    elif init:
        model.load_state_dict(torch.load(init, map_location=dev, weights_only=False)["model"])
        log(f"starting from the weights of {init}")
    with open(os.path.join(run_dir, "run.json"), "w") as fh:
        json.dump(meta, fh, indent=1)
    lossf = open(os.path.join(run_dir, "loss.csv"), "a")
    valf = open(os.path.join(run_dir, "val.csv"), "a")
    if start == 0:
        lossf.write("step,loss," + ",".join(task.loss_terms) + ",lr,seconds\n")
        valf.write("step," + ",".join(task.val_terms) + "\n")

    def checkpoint(step):
        _save({"model": model.state_dict(), "opt": opt.state_dict(), "step": step,
               "best": best, "meta": meta}, last)

    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=steps, initial=start, unit="step", desc=f"train {task.name}")
    step = start
    t_run = time.perf_counter()
    try:
        model.train()
        while step < steps:
            t0 = time.perf_counter()
            cur_lr = lr_at(step, steps, lr)
            for g in opt.param_groups:
                g["lr"] = cur_lr
            batch = {k: v.to(dev) for k, v in task.batch(seed, step).items()}
            terms = task.loss(model, batch)
            loss = sum(terms.values())
            opt.zero_grad(set_to_none=True)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
            opt.step()
            step += 1
            lossf.write(f"{step},{loss.item():.6f},"
                        + ",".join(f"{terms[k].item():.6f}" for k in task.loss_terms)
                        + f",{cur_lr:.3e},{time.perf_counter() - t0:.3f}\n")
            if step % 50 == 0:
                lossf.flush()
            if bar is not None:
                bar.update(1)
                bar.set_postfix(loss=f"{loss.item():.4f}")
            if step % ckpt_every == 0 or step == steps:
                if step % val_every == 0 or step == steps:
                    model.eval()
                    with torch.no_grad():
                        scores = task.validate(model, dev)
                    model.train()
                    valf.write(f"{step}," + ",".join(f"{scores[k]:.4f}"
                                                     for k in task.val_terms) + "\n")
                    valf.flush()
                    log(f"step {step}: " + ", ".join(f"{k} {v:.3f}" for k, v in scores.items()))
                    key = scores[task.val_terms[0]]
                    if best is None or key > best:
                        best = key
                        _save({"model": model.state_dict(), "step": step, "score": key,
                               "meta": meta}, os.path.join(run_dir, "best.pt"))
                checkpoint(step)
    except KeyboardInterrupt:
        checkpoint(step)
        raise
    finally:
        if bar is not None:
            bar.close()
        lossf.close()
        valf.close()
    return {"steps": step, "best": best, "seconds": time.perf_counter() - t_run}
