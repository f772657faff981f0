"""`--executor dask`: sequences and farm chunks spread over Dask distributed workers.

    fgen interpolate shots/*/ out/ --executor dask                       # local cluster
    fgen interpolate shots/*/ out/ --executor dask --scheduler tcp://farm:8786

Every task is one `run_sequence` call on a chunk (`--chunk K/N` semantics): it reads the
input frames its outputs need and writes its own frames atomically, so a task that runs
twice (Dask reschedules the tasks of a worker that died) writes the same bytes, and a
half-finished attempt leaves no corrupt frame. Errors of the input (FgenError) come back as
data and are not retried; anything else is retried by Dask. The command fails (exit 1)
naming every frame that was not written. Imported only with `--executor dask`.
"""
from __future__ import annotations

import os
import time
import uuid
from dataclasses import replace

from fgcli.batch import (RunTask, error_result, execute, open_task, plan_task, split_chunks)
from fgcli.errors import FgenError, UsageError


class ExecutorError(FgenError):
    """Some tasks failed; the message names the frames that were not written."""

    exit_code = 1


def _worker_call(fn, arg, queue_name: str | None, threads: int | None):
    """Runs on a worker: `fn(arg, on_frame)`, with progress sent to the client's queue."""
    if threads:
        import torch

        torch.set_num_threads(threads)
    on_frame = None
    if queue_name:
        from distributed import Queue

        on_frame = Queue(queue_name).put  # progress: frames finished
    try:
        return fn(arg, on_frame)
    except FgenError as e:  # bad input: reported as data, never retried
        return error_result(arg, e)


def _run_task(task: RunTask, on_frame):
    return execute(task, progress=False, on_frame=on_frame)


def _run_eval(task, on_frame):
    from fgcli.batch import execute_eval

    return execute_eval(task, progress=False, on_frame=on_frame)


def eval_dask(tasks: list, scheduler: str | None = None, workers: int | None = None,
              progress: bool = True, total_frames: int = 0) -> list[dict]:
    """Score several sequences on Dask, one task each; results in order. Raises
    ExecutorError naming the sequences that failed."""
    cl = Cluster(scheduler, workers)
    try:
        results = cl.map(_run_eval, tasks, total_frames, progress,
                         f"eval (dask, {cl.workers} workers)")
    finally:
        cl.close()
    failed = [(t, r) for t, r in zip(tasks, results) if not (isinstance(r, dict) and "error" not in r)]
    if failed:
        raise ExecutorError(f"{len(failed)} of {len(tasks)} sequences failed: " + "; ".join(
            f"{t.label()}: " + (r["error"] if isinstance(r, dict) else f"{type(r).__name__}: {r}")
            for t, r in failed))
    return results


class Cluster:
    """A Dask client: on `scheduler`, or on a local cluster of `workers` processes
    (one thread each; torch gets cores / workers threads)."""

    def __init__(self, scheduler: str | None = None, workers: int | None = None):
        try:
            from distributed import Client, LocalCluster
        except ImportError:
            raise UsageError("--executor dask needs dask.distributed: pip install "
                             "'fgcli[dask]'") from None
        import logging

        logging.getLogger("distributed").setLevel(logging.ERROR)
        self.cluster = None
        cores = os.cpu_count() or 1
        if scheduler:
            self.client = Client(scheduler, timeout="30s")
            self.threads = None  # the workers' own setting
        else:
            n = workers or cores
            self.threads = max(1, cores // n)
            self.cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                        dashboard_address=None, silence_logs=logging.ERROR)
            self.client = Client(self.cluster)
        self.workers = max(1, len(self.client.scheduler_info().get("workers", {})) or (workers or cores))

    def map(self, fn, args: list, total_frames: int, progress: bool, desc: str) -> list:
        """fn(arg, on_frame) for every arg on the workers; results in order (an exception
        object where a task failed for good). One progress bar over all frames."""
        from distributed import Queue, wait
        from tqdm import tqdm

        qname = f"fgen-progress-{uuid.uuid4().hex}"
        q = Queue(qname, client=self.client)
        futs = [self.client.submit(_worker_call, fn, a, qname, self.threads, pure=False,
                                   retries=2, key=f"fgen-{i}-{uuid.uuid4().hex[:8]}")
                for i, a in enumerate(args)]
        bar = tqdm(total=total_frames, desc=desc, unit="frame", disable=None if progress else True,
                   leave=False)
        try:
            while True:
                n = sum(q.get(batch=True))
                if n:
                    bar.update(min(n, bar.total - bar.n))
                if all(f.done() for f in futs):
                    n = sum(q.get(batch=True))
                    bar.update(min(n, bar.total - bar.n))
                    break
                time.sleep(0.1)
            wait(futs)
        finally:
            bar.close()
        out = []
        for f in futs:
            if f.status == "finished":
                out.append(f.result())
            else:
                out.append(f.exception())
        return out

    def close(self):
        self.client.close()
        if self.cluster is not None:
            self.cluster.close()


def run_dask(tasks: list[RunTask], scheduler: str | None = None, workers: int | None = None,
             progress: bool = True, chunks: int | None = None) -> list[tuple[RunTask, dict]]:
    """Run the tasks on Dask, each sequence split into `chunks` parts (default: the number
    of workers). Returns (chunk task, summary) pairs; raises ExecutorError naming the
    frames of the failed ones."""
    from fgcli.io.output import is_complete

    # on the client, before any work: every output folder made (stale temporary files of
    # killed runs removed), existing outputs refused unless --overwrite / --resume
    prepared = []
    for t in tasks:
        reader, out, _ = open_task(t)
        out.check_all([out.path_for(n) for n in plan_task(t, reader)["outputs"]])
        prepared.append((t, reader))
    cl = Cluster(scheduler, workers)
    try:
        per = chunks or cl.workers
        work, plans = [], []
        for t, reader in prepared:
            # a retried chunk keeps what its first attempt finished (--overwrite: rewrites)
            kw = dict(t.out_kw)
            if not kw.get("overwrite"):
                kw["resume"] = True
            for w in split_chunks([replace(t, out_kw=kw)], per):
                work.append(w)
                plans.append(plan_task(w, reader))
        total = sum(len(p["outputs"]) for p in plans)
        results = cl.map(_run_task, work, total, progress,
                         f"{tasks[0].pipeline} {tasks[0].mode} (dask, {cl.workers} workers)")
    finally:
        cl.close()
    ok, failed = [], []
    for w, plan, r in zip(work, plans, results):
        if isinstance(r, dict) and "error" not in r:
            ok.append((w, r))
            continue
        _, out, _ = open_task(replace(w, out_kw={**w.out_kw, "resume": True}))
        missing = [os.path.basename(out.path_for(n)) for n in plan["outputs"]
                   if not is_complete(out.path_for(n))]
        why = r["error"] if isinstance(r, dict) else f"{type(r).__name__}: {r}"
        failed.append((w, missing, why))
    if failed:
        lines = [f"{w.label()}: frames not written: {', '.join(m) if m else 'none'} ({why})"
                 for w, m, why in failed]
        raise ExecutorError(f"{len(failed)} of {len(work)} tasks failed; " + "; ".join(lines))
    write_merged_runs(ok)
    return ok


def write_merged_runs(results: list) -> None:
    """One OUT/fgen-run.json per output folder of a chunked run: what each chunk's own
    fgen-run.chunk-K-of-N.json says, gathered (written frames, cuts, the chunk files)."""
    import json

    from fgcli.io import atomic

    by_out: dict = {}
    for task, summary in results:
        by_out.setdefault(task.out_dir, []).append((task, summary))
    for out_dir, items in by_out.items():
        items.sort(key=lambda ts: ts[0].chunk or (0, 0))
        first = items[0][1]
        merged = {k: first.get(k) for k in ("pipeline", "mode", "alphas", "input",
                                            "input_frames", "timeline_scale", "command",
                                            "device", "backend") if k in first}
        merged["executor"] = "dask"
        merged["chunks"] = [{"chunk": s.get("chunk"),
                             "file": f"fgen-run.chunk-{t.chunk[0]}-of-{t.chunk[1]}.json"
                             if t.chunk else "fgen-run.json",
                             "written": s["written"], "outputs": s.get("outputs", []),
                             "ms_per_frame": s["timings"]["ms_per_frame"]} for t, s in items]
        merged["written"] = sum(s["written"] for _, s in items)
        merged["skipped_existing"] = sum(s["skipped_existing"] for _, s in items)
        merged["scene_cuts"] = sorted({c for _, s in items
                                       for c in (s.get("scene_cuts") or {}).get("cuts", [])})
        atomic.write_text(os.path.join(out_dir, "fgen-run.json"), json.dumps(merged, indent=1))
