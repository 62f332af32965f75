"""Summarise finished sweeps (runs/<name>/sweep.json) as Markdown: one row per point with its
learning curve (dense train success at each evaluation) and final scores per protocol.

    python experiments/study_table.py runs/sw1-lr-tau [runs/...] [--copy results/study docs/figures]

--copy DATA FIGS: also copy each sweep.json to DATA/<name>.json and curves.png to FIGS/<name>.png.
"""
import json
import os
import shutil
import sys

import numpy as np


def summary(path: str) -> str:
    d = json.load(open(os.path.join(path, "sweep.json")))
    cfg = d["config"]
    name = os.path.basename(path.rstrip("/"))
    out = [f"**{name}** ({cfg['env']} {cfg['algo']}, {cfg['n_train_layouts']} layouts, {cfg['num_seeds']} seed(s), "
           f"{cfg['steps']} updates, d={cfg['d']}, splus={cfg['splus']}, target={cfg['target_policy']}):", "",
           "| setting | dense train over updates | final dense train / test | paper train / test | random_start train / test |",
           "|---|---|---|---|---|"]
    for p in d["points"]:
        curve = " ".join(f"{np.mean(c['eval/train/dense']):.2f}" for c in p["curve"] if "eval/train/dense" in c)
        pr = p["protocols"]
        f = lambda k: f"{np.mean(pr[k]['train']):.2f} / {np.mean(pr[k]['test']):.2f}" if k in pr else "-"
        out.append(f"| {p['label']} | {curve} | {f('dense')} | {f('paper')} | {f('random_start')} |")
    return "\n".join(out)


if __name__ == "__main__":
    args = sys.argv[1:]
    copy = None
    if "--copy" in args:
        i = args.index("--copy")
        copy, args = args[i + 1:i + 3], args[:i] + args[i + 3:]
    for path in args:
        print(summary(path) + "\n")
        if copy:
            name = os.path.basename(path.rstrip("/"))
            shutil.copy(os.path.join(path, "sweep.json"), os.path.join(copy[0], name + ".json"))
            if os.path.exists(os.path.join(path, "curves.png")):
                shutil.copy(os.path.join(path, "curves.png"), os.path.join(copy[1], name + ".png"))
