"""Render mv-interp training samples in parallel (seeds split over worker processes):

    python scripts/render_training_data.py DATA N_TRAIN N_LIGHT N_VAL PROCESSES

then `fgen train mv-interp --data DATA ...` finds them rendered (same seeds and files as
its own serial rendering: fgcli.nets.data.make_samples)."""
import os, sys
os.environ["OMP_NUM_THREADS"] = "1"
from multiprocessing import Pool

def work(args):
    folder, seeds = args
    import torch
    torch.set_num_threads(1)
    from fgcli.nets.data import make_samples
    return make_samples(folder, seeds, progress=False)

if __name__ == "__main__":
    from fgcli.nets.data import HELDOUT_SEEDS, LIGHT_SEEDS
    root, n_train, n_light, n_val, procs = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4]), int(sys.argv[5])
    jobs = []
    for folder, seeds in ((f"{root}/val", range(HELDOUT_SEEDS[0], HELDOUT_SEEDS[0] + n_val)),
                          (f"{root}/train", range(n_train)),
                          (f"{root}/train_light", range(LIGHT_SEEDS[0], LIGHT_SEEDS[0] + n_light))):
        os.makedirs(folder, exist_ok=True)
        s = list(seeds)
        jobs += [(folder, s[i::procs]) for i in range(procs) if s[i::procs]]
    with Pool(procs) as p:
        print(sum(p.map(work, jobs)), "samples", flush=True)
