"""A saved run's paper-protocol score averaged over several evaluation draws.

    python experiments/fb_diagnostics/eval_keys.py runs/<run> [--encoder-of runs/<run_b>] [--keys 8]
        [--json results/fourrooms_eval_keys.jsonl]
    python experiments/fb_diagnostics/eval_keys.py runs/<f_0> runs/<f_1> ... --encoder-of runs/<e_0> runs/<e_1> ...

One evaluation of Four-Rooms' 20 held-out layouts is 60 tasks, each with one context draw:
its success rate has a binomial standard error of about 0.06, the size of the differences
between encoder variants. This scores the run (seed 0) with the run's own evaluation keys
(what it reported) and --keys - 1 fresh ones (`zsbfm.evaluate.score_draws`: fresh context
episodes and rollouts, the same layouts and goals), on train and held-out layouts, and
prints the mean and its standard error over the draws (sample std / sqrt(keys)).
--encoder-of: F and B of the run with another run's encoder and head (h_swap.py
--encoder-of; both h_train_true); the draws are then under that run's config, so draw 0 is
that run's own evaluation keys.
Several runs (with as many --encoder-of, paired by position: independently trained
seeds): each is scored as above, then the mean over the runs of their means over draws and
its standard error over the runs (sample std / sqrt(runs)), the seed-to-seed spread.
--context-read: h read off the context this way (h_swap.py --context-read).
--context-episodes K: test-time contexts of K episodes instead of the run's own number
(Config.context_episodes; 1 is the paper's protocol).
"""
from __future__ import annotations

import argparse
import json

import numpy as np

import zsbfm
from zsbfm.evaluate import score_draws, standard_error
from zsbfm.names import CONTEXT_READS

from h_swap import with_encoder_of, with_read  # this script's folder is on sys.path


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("runs", nargs="+", metavar="RUN")
    p.add_argument("--encoder-of", nargs="*", default=[], metavar="RUN_B",
                   help="one per RUN (paired by position), or none")
    p.add_argument("--keys", type=int, default=8, help="evaluation draws: the run's own, then fresh ones")
    p.add_argument("--protocol", default="paper")
    p.add_argument("--context-read", default="", choices=["", *CONTEXT_READS],
                   help="read h off the context this way (Config.context_read) instead of the run's own")
    p.add_argument("--context-episodes", type=int, default=0,
                   help="episodes per test-time context (0: the run's own context_episodes)")
    p.add_argument("--json", default="")
    a = p.parse_args()
    if a.keys <= 0:
        p.error(f"--keys must be a positive integer, got {a.keys}")
    if a.context_episodes < 0:
        p.error(f"--context-episodes must be a positive integer (0: the run's own), got {a.context_episodes}")
    if a.encoder_of and len(a.encoder_of) != len(a.runs):
        p.error(f"--encoder-of: {len(a.encoder_of)} runs for {len(a.runs)} RUNs; give one per RUN or none")
    means = {"train": [], "test": []}
    for i, path in enumerate(a.runs):
        encoder_of = a.encoder_of[i] if a.encoder_of else ""
        print(path, flush=True)  # with_encoder_of names the encoder run
        run = zsbfm.load(path)
        if encoder_of:
            run = with_encoder_of(run, encoder_of)
        run = with_read(run, a.context_read)
        episodes = {"context_episodes": a.context_episodes} if a.context_episodes else {}  # else the run's own
        out = {"run": path, "encoder_of": encoder_of, "protocol": a.protocol, "keys": a.keys,
               **({"context_read": run.cfg.context_read} if run.cfg.context_read != "head" else {}), **episodes}
        for split in ("train", "test"):
            scores = [float(x) for x in score_draws(run, a.keys, split, a.protocol, **episodes)[:, 0]]  # seed 0
            out[split] = scores
            means[split].append(float(np.mean(scores)))
            print(f"  {split:5s} {a.protocol}: {np.mean(scores):.3f} +- {float(standard_error(scores)):.3f} "
                  f"(se over {len(scores)} draws; the run's own {scores[0]:.3f})", flush=True)
        if a.json:
            with open(a.json, "a") as f:
                f.write(json.dumps(out) + "\n")
    if len(a.runs) > 1:
        for split, m in means.items():
            print(f"over the {len(m)} runs, {split:5s} {a.protocol}: {np.mean(m):.3f} +- {float(standard_error(m)):.3f} "
                  f"(se over runs; each run's mean over draws: {', '.join(f'{x:.3f}' for x in m)})")


if __name__ == "__main__":
    main()
