"""FB vs Belief-FB vs Rotation-FB on one environment, 3 vmapped seeds each (CPU preset).

    python experiments/belief_table.py --env fourrooms        # writes results/belief_fourrooms.{json,md}
    python experiments/belief_table.py --env doors --set steps=6000

Each method is an ordinary `zsbfm.train` run under runs/<env>-<algo>-cpu (so a killed
sweep resumes where it stopped, and finished methods are not retrained). The table gives
mean +- std over seeds of the success rate on the train and the 20 held-out test layouts,
the paper's values where it has them, and each method's wall time.
"""

from __future__ import annotations

import argparse
import json
import os

import numpy as np

import zsbfm

# Paper, Tables 1-2 (Randomized Four-Rooms, 20 train / 20 test layouts): (train, test).
PAPER = {"fourrooms": {"fb": (0.25, 0.15), "bfb": (0.70, 0.40), "rfb": (0.85, 0.61)}}
NAMES = {"fb": "FB", "bfb": "Belief-FB", "rfb": "Rotation-FB"}


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--env", default="fourrooms")
    p.add_argument("--algos", nargs="+", default=["fb", "bfb", "rfb"])
    p.add_argument("--seeds", type=int, default=3)
    p.add_argument("--runs-dir", default="runs")
    p.add_argument("--out", default="results")
    p.add_argument("--set", nargs="*", default=[], help="Config overrides for every method")
    a = p.parse_args()

    rows = {}
    for algo in a.algos:
        cfg = zsbfm.Config.preset(a.env, algo, num_seeds=a.seeds, runs_dir=a.runs_dir).with_overrides(a.set)
        print(f"== {algo}: {cfg.run_name}", flush=True)
        run = zsbfm.train(cfg)
        r = run.results
        rows[algo] = {"train": r["train"], "test": r["test"], "wall_time_s": r["wall_time_s"],
                      "run": os.path.join(cfg.runs_dir, cfg.run_name)}

    os.makedirs(a.out, exist_ok=True)
    with open(os.path.join(a.out, f"belief_{a.env}.json"), "w") as f:
        json.dump(rows, f, indent=2)
    paper = PAPER.get(a.env, {})
    lines = [f"| {a.env} ({a.seeds} seeds, CPU preset) | train success | test success | paper train / test | wall time (train + eval) |",
             "|---|---|---|---|---|"]
    for algo, row in rows.items():
        tr, te = np.asarray(row["train"]), np.asarray(row["test"])
        pp = paper.get(algo)
        wt = row["wall_time_s"]
        lines.append(f"| {NAMES[algo]} | {tr.mean():.2f} +- {tr.std():.2f} | {te.mean():.2f} +- {te.std():.2f} | "
                     f"{f'{pp[0]:.2f} / {pp[1]:.2f}' if pp else 'n/a'} | {wt['train'] + wt['eval']:.0f} s |")
    table = "\n".join(lines)
    with open(os.path.join(a.out, f"belief_{a.env}.md"), "w") as f:
        f.write(table + "\n")
    print(table)


if __name__ == "__main__":
    main()
