"""Per-stage and per-frame cost of every pipeline at 1920x1080 on this machine.

    python benchmarks/stages.py [--size 1920x1080] [--repeat 7] [--pipelines mob-fgsr,...]
                                [--backends torch,numba] [--sequence] [--json FILE]
                                [--input FOLDER [--frames RANGE]]

Frames come from the bundled `blade` scene rendered at the benchmark size (fast movers,
disocclusions: the expensive case; a static camera), its vectors rounded to 1/1024 px as
`fgen synth` writes them (`--mv-step`): the static set's vectors are exactly zero, as in
the shipped sample data and a rasteriser's output. By default every generated frame comes from the same
pair with no state (each as a sequence's first frame); `--sequence` generates from
consecutive pairs with the run's state carried over, the steady state `fgen` reaches on a
sequence (GFFE's history and background layers, FSR 3's memoised luminance). `--input`
takes the frames from an EXR sequence instead (any layout fgen reads: real renders, whose
motion is larger and less regular than the scene's; `--size` is then the footage's).
Prints median ms per stage and per generated frame,
EXR read/write times separately, and every figure as a ratio to a reference measured in the
same run (a plain copy of one frame's color+depth+mv tensors, copy_ms), so figures compare
across machines. Both backends (torch reference ops, numba kernels) run interleaved in one
run, so their ratio is visible. Compute excludes I/O. Target (issue 9): mob-fgsr
interpolation <= 50 ms (<= 12x copy_ms) per 1080p frame on 2 cores, extrapolation <= 35 ms,
the other heuristic pipelines <= 60 ms.
"""
from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time

# as the CLI does: torch's OpenMP threads must not spin (set before torch is imported)
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)


def cpu_model() -> str:
    """The CPU as /proc/cpuinfo names it, with its family / model numbers (a VM's model name
    alone, e.g. "AMD EPYC", does not tell a Zen 3 from a Zen 5) and its widest vectors."""
    info = {}
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if not line.strip():
                    break  # the first CPU's block
                k, _, v = line.partition(":")
                info[k.strip()] = v.strip()
    except OSError:
        import platform

        return platform.processor() or platform.machine()
    flags = info.get("flags", "").split()
    simd = "AVX-512" if "avx512f" in flags else "AVX2" if "avx2" in flags else "no AVX2"
    return (f"{info.get('model name', '?')} (family {info.get('cpu family', '?')} model "
            f"{info.get('model', '?')}, {simd})")


def openmp_env() -> dict:
    """The OpenMP wait settings the run used (torch's runtime, which numba's kernels share:
    the spin after each parallel region changes every figure; docs/performance.md)."""
    return {k: os.environ.get(k, "(unset)") for k in ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT")}


def median_ms(fn, repeat):
    fn()  # warm-up
    xs = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        xs.append((time.perf_counter() - t0) * 1000)
    return statistics.median(xs)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", default="1920x1080")
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--pipelines", default="all")
    ap.add_argument("--scene", default=os.path.join(ROOT, "sample_data", "scenes", "blade.toml"))
    ap.add_argument("--threads", type=int, default=0, help="torch threads (0 = default)")
    ap.add_argument("--backends", default="torch,numba",
                    help="comma-separated backends, timed side by side (the last is the one "
                         "the JSON's top-level figures report)")
    ap.add_argument("--device", default="cpu",
                    help="cpu, or cuda[:N]: the torch backend on the GPU (issue 9 item 6); "
                         "every stage is synchronised before its clock is read")
    ap.add_argument("--sync-report", action="store_true",
                    help="CUDA: run each pipeline once more under torch's sync debug mode and "
                         "list every host round-trip the stages make (file:line, stage); the "
                         "per-frame facts (motion test, scene-cut histogram) are counted apart")
    ap.add_argument("--sequence", action="store_true",
                    help="steady state: each repeat generates from the next pair of "
                         "consecutive frames (repeat + 1 of them) with the run's state "
                         "carried over, as `fgen` does on a sequence (GFFE's history and "
                         "layers, FSR 3's memoised luminance); the first pair (empty "
                         "history) is the warm-up. Default: one pair, no state (each frame "
                         "as a sequence's first)")
    ap.add_argument("--input", default=None, metavar="FOLDER",
                    help="frames from this EXR sequence (its first frames, or --frames) "
                         "instead of the rendered scene")
    ap.add_argument("--mv-step", type=float, default=None, metavar="PX",
                    help="the rendered scene's motion vectors are rounded to multiples of PX "
                         "(a power of two) before the upscale, as `fgen synth` writes them "
                         "(default 2**-10: static surfaces get exact zeros, as in every file "
                         "fgen synth writes and a rasteriser's vectors); 0: the tracer's "
                         "unrounded float32 vectors (~1e-5 px of noise at static pixels)")
    ap.add_argument("--frames", default=None, metavar="RANGE",
                    help="with --input: the frames to use, oiiotool style (1-3, 1001-1010)")
    ap.add_argument("--json", default=None, metavar="FILE",
                    help="also write the figures as JSON: {copy_ms, pipelines: {name: {mode: "
                         "{ms_per_frame, x_copy, stages, backends: {torch: ..., numba: ...}}}}}")
    args = ap.parse_args()
    import torch

    from fgcli import pipeline as pl
    from fgcli.io.frames import read_frame, write_frame
    from fgcli.pipeline import Timings, run_stages
    from fgcli.runner import RunState, make_ctx
    from fgcli.synth import load_scene, render
    from fgcli.synth.sequence import MV_STEP

    from ab import upscaled  # (this folder: the frames as ab.py and kernels.py make them)

    from fgcli.runner import check_device

    dev = check_device(args.device)  # what fgen does at start-up (allocator tuning)
    cuda = dev.startswith("cuda")
    sync = torch.cuda.synchronize if cuda else None
    if args.threads:
        torch.set_num_threads(args.threads)
    n_frames = args.repeat + 2 if args.sequence else 2
    if args.input:
        from fgcli.io.reader import SequenceReader

        reader = SequenceReader(args.input, frames=args.frames)  # (every field present)
        if len(reader.numbers) < n_frames:
            sys.exit(f"--input: {n_frames} frames needed, {len(reader.numbers)} selected")
        seq = [reader.read(n).replace(normal=None, albedo=None, roughness=None, alpha=None)
               for n in reader.numbers[:n_frames]]
        W, H = reader.width, reader.height
        step = None  # (the files' own vectors)
        source = (f"frames {reader.numbers[0]}-{reader.numbers[n_frames - 1]} of "
                  f"{args.input} ({reader.info.layout} layout)")
    else:
        W, H = (int(v) for v in args.size.lower().split("x"))
        step = MV_STEP if args.mv_step is None else args.mv_step
        # render at 1/4 size and upscale (nearest; vectors x4): same motion structure, fast
        scene = load_scene(args.scene, size=(W // 4, H // 4))
        t0 = time.perf_counter()
        times = ([(2.0 + 0.5 * i, 1.0 + 0.5 * i) for i in range(args.repeat + 2)]
                 if args.sequence else [(3.0, 2.0), (4.0, 3.0)])
        small = [render(scene, t, tp, spp=2) for t, tp in times]
        render_ms = (time.perf_counter() - t0) * 1000 / len(small)

        # (GFFE tracks once per rendered frame number)
        seq = [upscaled(f, W, H, step).replace(number=i) for i, f in enumerate(small)]
        source = (f"frames from {os.path.basename(args.scene)} rendered at 1/4 size and "
                  f"upscaled, vectors " + (f"rounded to {step:g} px as fgen synth writes "
                                           "them" if step else "unrounded") +
                  f" (render {render_ms:.0f} ms/frame, not counted)")
    host1 = seq[1]
    if cuda:
        seq = [f.to(dev) for f in seq]
        torch.cuda.synchronize()
    f0, f1 = seq[0], seq[1]
    where = (f"{torch.cuda.get_device_name(dev)}" if cuda else
             f"{torch.get_num_threads()} threads")
    print(f"# {W}x{H}, torch {torch.__version__}, {where}; "
          f"{'a sequence (state carried), ' if args.sequence else ''}{source}")
    if not cuda:
        print(f"# {cpu_model()}; OpenMP: " + ", ".join(f"{k}={v}" for k, v in
                                                       openmp_env().items()))

    def copy_frame():
        out = (f1.color.clone(), f1.depth.clone(), f1.mv.clone())
        if sync is not None:
            sync()
        return out

    def copy_sample():
        copy_frame()  # (as at the start: a timed copy follows a copy, not a pipeline run)
        t0 = time.perf_counter()
        copy_frame()
        return (time.perf_counter() - t0) * 1000

    # the reference is sampled again between the pipelines' runs (its median over a run
    # moved 1.9-6.0 ms between runs on the 2-core box when it was taken once at the start,
    # which made the ratios noise); x_copy divides by the samples taken while that
    # pipeline ran, copy_ms is the median of all
    copy_frame()
    copy_samples = [copy_sample() for _ in range(args.repeat)]
    ref = statistics.median(copy_samples)
    print(f"reference: copy one frame's color+depth+mv tensors = {ref:.2f} ms (at the start; "
          f"resampled between the pipelines' runs)\n")

    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "f.0001.exr")
        w_ms = median_ms(lambda: write_frame(path, host1), max(3, args.repeat // 2))
        r_ms = median_ms(lambda: read_frame(path, 1, fields={"color", "depth", "mv"}),
                         max(3, args.repeat // 2))
        size_mb = os.path.getsize(path) / 1e6
    print(f"EXR write (fgen layout, half color, float depth/mv, zip): {w_ms:.1f} ms "
          f"({w_ms / ref:.0f}x ref), {size_mb:.1f} MB")
    print(f"EXR read  (color+depth+mv):                               {r_ms:.1f} ms "
          f"({r_ms / ref:.0f}x ref)\n")

    # start-up: a fresh process loading every numba kernel from the on-disk cache (the
    # first call may compile them; the second is what every later fgen run pays)
    import subprocess

    code = "from fgcli.kernels.ops import warm; print(warm())"
    loads = []
    for _ in range(0 if cuda else 2):  # CUDA runs the torch ops: no CPU kernels to load
        r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                           cwd=ROOT)
        loads.append(float(r.stdout.strip().splitlines()[-1]) * 1000 if r.returncode == 0
                     else float("nan"))
    core_ms = float("nan")
    if not loads:
        loads = [float("nan")] * 2
    else:
        # what a mob-fgsr / mv-warp / blend run loads (fgen loads only its pipeline's
        # kernel families)
        r = subprocess.run([sys.executable, "-c", "from fgcli.kernels.ops import warm; "
                            "print(warm(families={'core'}))"], capture_output=True, text=True,
                           cwd=ROOT)
        if r.returncode == 0:
            core_ms = float(r.stdout.strip().splitlines()[-1]) * 1000
        print(f"numba kernels, fresh process: first {loads[0]:.0f} ms (compiles when the cache "
              f"is cold), then {loads[1]:.0f} ms (cached; all of them), {core_ms:.0f} ms "
              f"for the shared ones alone (what mob-fgsr loads)\n")
    names = list(pl.available()) if args.pipelines == "all" else args.pipelines.split(",")
    backends = [b.strip() for b in args.backends.split(",") if b.strip()]
    from fgcli.kernels import resolve

    backends = list(dict.fromkeys(resolve(b, dev) for b in backends))  # CUDA: torch only
    result = {"size": [W, H], "sequence": bool(args.sequence), "frames": source,
              "mv_step": step,
              "threads": torch.get_num_threads(), "torch": torch.__version__,
              "device": torch.cuda.get_device_name(dev) if cuda else "cpu",
              "cpu": cpu_model(), "openmp": openmp_env(),
              "copy_ms": ref, "exr_write_ms": w_ms, "exr_read_ms": r_ms, "backends": backends,
              "kernel_load_ms": {"first_process": loads[0], "cached": loads[1],
                                 "cached_core": core_ms},
              "pipelines": {}}
    cols = " | ".join(f"{b} ms/frame | {b} x copy" for b in backends)
    print(f"| pipeline | mode | {cols} | speed-up | stages (median ms, "
          f"{' / '.join(backends)}) |")
    print("|---|---|" + "---|---|" * len(backends) + "---|---|")
    sync_lines, stream_lines = [], []
    with torch.inference_mode():
        for name in names:
            p = pl.load(name)
            if p.scale_only:  # super-resolution baselines: the --scale 2 table below
                continue
            for mode in p.modes:
                stages = p.build(mode)
                tms = {b: Timings() for b in backends}
                first = {}
                local = []  # the reference, sampled between this pipeline's runs
                try:
                    # interleaved: torch, numba, torch, ... so load changes hit both alike;
                    # the first run of each backend (numba: loading/compiling kernels) is
                    # the warm-up Timings.median drops
                    states = {b: RunState() for b in backends}
                    for k in range(args.repeat + 1):
                        for b in backends:
                            if args.sequence:  # the next pair, the state carried over
                                ctx = make_ctx(seq[k], seq[k + 1], 0.5, mode)
                                ctx["state"] = states[b]
                            else:
                                ctx = make_ctx(f0, f1, 0.5, mode)
                                ctx["state"] = None
                            ctx["prev_time"] = 0.0
                            ctx["backend"] = b
                            t0 = time.perf_counter()
                            run_stages(stages, ctx, tms[b], sync=sync)
                            if k == 0:
                                first[b] = (time.perf_counter() - t0) * 1000.0
                        local.append(copy_sample())
                except Exception as e:  # noqa: BLE001 - a benchmark reports and goes on
                    print(f"| {p.label} | {mode} | error: {type(e).__name__}: {e} |")
                    continue
                summ = {b: tms[b].summary() for b in backends}
                copy_samples += local
                lref = statistics.median(local)
                entry = {}
                for b in backends:
                    s = summ[b]
                    entry[b] = {"ms_per_frame": s["ms_per_frame"],
                                "x_copy": s["ms_per_frame"] / lref,
                                "first_call_ms": first[b], "stages": s["stages"]}
                main_b = backends[-1]
                result["pipelines"].setdefault(p.label, {})[mode] = {
                    "ms_per_frame": entry[main_b]["ms_per_frame"],
                    "x_copy": entry[main_b]["x_copy"], "copy_ms": lref, "backend": main_b,
                    "stages": entry[main_b]["stages"], "backends": entry}
                if cuda:
                    # frames back to back with no clock read between stages or frames, one
                    # synchronise at the end: what a run costs when the GPU is never idle
                    # waiting for the host (the per-frame facts still read back once)
                    def frames(n):
                        for _ in range(n):
                            ctx = make_ctx(f0, f1, 0.5, mode)
                            ctx.update(prev_time=0.0, state=None, backend=main_b)
                            run_stages(stages, ctx, None)
                        torch.cuda.synchronize()

                    frames(2)
                    t0 = time.perf_counter()
                    frames(4 * args.repeat)
                    thr = (time.perf_counter() - t0) * 1000.0 / (4 * args.repeat)
                    result["pipelines"][p.label][mode]["stream_ms_per_frame"] = thr
                    stream_lines.append(f"{p.label} {mode}: {thr:.2f} ms/frame streamed "
                                        f"({entry[main_b]['ms_per_frame']:.2f} with a clock "
                                        f"read after every stage)")
                figs = " | ".join(f"{entry[b]['ms_per_frame']:.1f} | {entry[b]['x_copy']:.1f}"
                                  for b in backends)
                sp = (entry[backends[0]]["ms_per_frame"] / max(entry[main_b]["ms_per_frame"], 1e-9)
                      if len(backends) > 1 else 1.0)
                st = ", ".join(f"{k} " + " / ".join(f"{summ[b]['stages'].get(k, 0.0):.1f}"
                                                    for b in backends)
                               for k in summ[main_b]["stages"])
                print(f"| {p.label} | {mode} | {figs} | {sp:.1f}x | {st} |")
                if cuda and args.sync_report:
                    try:
                        rep = sync_report(stages, f0, f1, mode, backends[-1])
                    except Exception as e:  # noqa: BLE001 - reported, the run goes on
                        import traceback

                        traceback.print_exc()
                        sync_lines.append(f"{p.label} {mode}: report failed: {e}")
                        continue
                    result["pipelines"][p.label][mode]["host_syncs"] = rep
                    vs = ", ".join(f"{k} max {v['max_abs']:.2g} mean {v['mean_abs']:.2g}"
                                   for k, v in rep["vs_cpu"].items())
                    sync_lines.append(f"{p.label} {mode}: facts {rep['facts']}, stages "
                                      f"{rep['stages']}; vs CPU: {vs}" + "".join(
                                          f"\n    {n} x {site}" for site, n in rep["sites"]))
                sys.stdout.flush()
    sr_names = [n for n in names if pl.load(n).scale_only or pl.load(n).has_sr]
    if sr_names:
        result["scale2"] = scale2_rows(sr_names, f0, f1, args.repeat, sync, backends[-1],
                                       statistics.median(copy_samples))
    result["copy_ms"] = statistics.median(copy_samples)
    print(f"\nreference over the run: copy_ms {result['copy_ms']:.2f} (median of "
          f"{len(copy_samples)} copies, {min(copy_samples):.2f}-{max(copy_samples):.2f}); "
          f"x copy above: against the copies taken while that pipeline ran")
    if stream_lines:
        print("\n" + "\n".join(stream_lines))
    if sync_lines:
        print("\nhost round-trips per generated frame (torch sync debug mode):")
        print("\n".join(sync_lines))
    if args.json:
        import json

        with open(args.json, "w") as fh:
            json.dump(result, fh, indent=1)
        print(f"\n(JSON: {args.json})")


def half_res(f, offset: int):
    """The frame as a half-resolution jittered render: every other pixel from (offset,
    offset), vectors halved; its jitter (offset + 0.5) / 2 - 0.5 LR pixels in x and y."""
    j = (offset + 0.5) / 2 - 0.5
    sl = (slice(None), slice(offset, None, 2), slice(offset, None, 2))
    return f.replace(color=f.color[sl].contiguous(), depth=f.depth[sl].contiguous(),
                     mv=(f.mv[sl] * 0.5).contiguous(), alpha=None, normal=None, albedo=None,
                     roughness=None, mv_valid=None, data_window=None, overscan=None,
                     header={**f.header, "fgen:jitter_x": j, "fgen:jitter_y": j})


def scale2_rows(names, f0, f1, repeat, sync, backend, ref) -> dict:
    """--scale 2 at the benchmark's size as the OUTPUT size: the input is the frames at
    half resolution (jittered), as a render farm or engine renders for super resolution.
    Per pipeline and mode: ms of the rendered frame's reconstruction (SS, with history) and
    of one generated frame (ESS) at the output size, per stage."""
    from fgcli import pipeline as pl
    from fgcli.pipeline import Timings
    from fgcli.runner import RunState
    from fgcli.sr import Reconstructor, generate

    lr = [half_res(f0, 0).replace(number=0), half_res(f1, 1).replace(number=1)]
    H, W = f1.color.shape[-2:]
    print(f"\n--scale 2: input {lr[0].width}x{lr[0].height} (jittered), output {W}x{H}; "
          f"SS = the rendered frame reconstructed (with history), ESS = one generated frame; "
          f"{backend} kernels for the generation stages")
    print("| pipeline | mode | SS ms/frame | ESS ms/frame | x copy (SS + ESS) | stages (median ms) |")
    print("|---|---|---|---|---|---|")
    out = {}
    for name in names:
        p = pl.load(name)
        for mode in p.modes:
            tm_ss, tm_ess = Timings(), Timings()
            for _ in range(repeat + 1):
                rec = Reconstructor(p, 2, lambda n: lr[n], [0, 1], backend, sync)
                rec.frame(0)  # the history (not timed)
                rec.frame(1, tm_ss)
                generate(p.build(mode), p.has_sr, rec, lr[0], lr[1], 0.5, mode, RunState(), 2,
                         backend, tm_ess, sync=sync)
            ss, ess = tm_ss.summary(), tm_ess.summary()
            st = ", ".join([f"sr:{k} {v:.1f}" for k, v in ss["stages"].items()]
                           + [f"{k} {v:.1f}" for k, v in ess["stages"].items()])
            tot = ss["ms_per_frame"] + ess["ms_per_frame"]
            print(f"| {p.label} | {mode} | {ss['ms_per_frame']:.1f} | {ess['ms_per_frame']:.1f} "
                  f"| {tot / ref:.1f} | {st} |")
            out.setdefault(p.label, {})[mode] = {
                "ss_ms_per_frame": ss["ms_per_frame"], "ess_ms_per_frame": ess["ms_per_frame"],
                "x_copy": tot / ref, "ss_stages": ss["stages"], "ess_stages": ess["stages"]}
            sys.stdout.flush()
    return out


def sync_report(stages, f0, f1, mode, backend) -> dict:
    """Host round-trips of one generated frame on CUDA: torch's sync debug mode warns at
    every synchronising call; each warning is attributed to the innermost fgcli frame of
    the Python stack (file:line) and the stage file that called it. Also runs the frame
    through the same stages on the CPU and reports how far the outputs are apart."""
    import traceback
    import warnings

    import torch

    from fgcli.pipeline import frame_facts, run_stages
    from fgcli.runner import make_ctx

    ctx = make_ctx(f0, f1, 0.5, mode)
    ctx.update(prev_time=0.0, state=None, backend=backend)
    sites: dict = {}
    counts = {"facts": 0, "stages": 0}
    phase = ["facts"]

    def show(message, category, filename, lineno, file=None, line=None):
        if "synchroniz" not in str(message):
            return
        counts[phase[0]] += 1
        stack = traceback.extract_stack()[:-1]
        here = [f for f in stack if "fgcli" in f.filename]
        site = (f"{os.path.relpath(here[-1].filename, ROOT)}:{here[-1].lineno}" if here
                else f"{filename}:{lineno}")
        via = [f for f in stack if os.sep + "stages" + os.sep in f.filename]
        if via and via[-1] is not here[-1]:
            site += f" (from {os.path.basename(via[-1].filename)}:{via[-1].lineno})"
        sites[(phase[0], site)] = sites.get((phase[0], site), 0) + 1

    old = warnings.showwarning
    warnings.showwarning = show
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("always")
            torch.cuda.synchronize()
            torch.cuda.set_sync_debug_mode("warn")
            try:
                facts = frame_facts(ctx)
                phase[0] = "stages"
                run_stages(stages, ctx, None, facts=facts)
            finally:
                torch.cuda.set_sync_debug_mode("default")
    finally:
        warnings.showwarning = old
    # the same frame through the same stages on the CPU (torch reference): how far apart
    cpu = make_ctx(f0.to("cpu"), f1.to("cpu"), 0.5, mode)
    cpu.update(prev_time=0.0, state=None, backend="torch")
    run_stages(stages, cpu, None)
    diff = {}
    for k in ("color", "depth", "mv"):
        a, b = ctx[k].float().cpu(), cpu[k].float()
        fin = torch.isfinite(a) & torch.isfinite(b)
        same_inf = (a == b) | fin
        d = (a - b).abs()[fin]
        diff[k] = {"max_abs": float(d.max()) if d.numel() else 0.0,
                   "mean_abs": float(d.mean()) if d.numel() else 0.0,
                   "frac_over_1e-3": float((d > 1e-3).float().mean()) if d.numel() else 0.0,
                   "nonfinite_mismatch": int((~same_inf).sum())}
    return {**counts, "sites": sorted(((f"[{ph}] {s}", n) for (ph, s), n in sites.items()),
                                      key=lambda x: -x[1]), "vs_cpu": diff}


if __name__ == "__main__":
    main()
