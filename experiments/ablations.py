"""Ablations of the paper's Figure 2 and of Rotation-FB's kappa, with plots.

    python experiments/ablations.py --which layouts   # 10/20/30/50 train layouts (Fig. 2 left)
    python experiments/ablations.py --which context   # context length 25/50/100 (Fig. 2 right)
    python experiments/ablations.py --which kappa     # Rotation-FB kappa 1/10/50/100/200
    python experiments/ablations.py --which kappa --set steps=6000   # shortened
    python experiments/ablations.py --which layouts --points 10 40 160 --seeds 1 --algos bfb \
        --set eval_every=4 --tag recipe                                  # 1e6 transitions each
    python experiments/ablations.py --which layouts --points 10 40 160 --seeds 1 --algos oracle \
        --set oracle_context=walls eval_every=4 --tag walls
    python experiments/ablations.py --which h_dim --points 16 32 150 --algos bfb
    python experiments/ablations.py --which h_noise --algos bfb      # h = mu vs mu + sigma eps

Each point is an ordinary `zsbfm.train` run (3 vmapped seeds, CPU preset unless --size)
named <env>-<algo>-<which>-<value>[-<tag>], so a killed sweep resumes and finished points
are read back; a point equal to the preset is the preset's own run, shared with
`make table`. --points replaces the swept values (for layouts: the number of train layouts,
each with 1e6 / (layouts x episode length) episodes).
Writes results/ablation_<which>_<env>[_<tag>].json and .png (success vs the swept value,
train and test, mean +- std over seeds; the paper protocol, and the dense one dashed): give
a --tag to keep the files of an earlier preset's sweep.

Dataset sizes for the layout sweep follow the paper (1e6 transitions in all):
(layouts, episodes per layout) = (10, 1000), (20, 500), (30, 250)*, (50, 150)*
(* as the paper lists them: these two hold 0.75e6 transitions); on pointmass (250-step
episodes) the episodes per maze are 1e6 / (mazes x 250).
Context length 200 (the paper's largest) is not swept: a context here is a window of one
episode, and episodes are 100 steps (gluing episodes is a known bug of the prototype).
"""

from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np

import table  # experiments/table.py: configs, read-back and resume of finished runs
from zsbfm.config import SIZES, Config

SWEEPS = {
    "layouts": [dict(n_train_layouts=n, episodes_per_layout=e) for n, e in ((10, 1000), (20, 500), (30, 250), (50, 150))],
    "context": [dict(context_len=n) for n in (25, 50, 100)],
    "kappa": [dict(kappa=float(k)) for k in (1, 10, 50, 100, 200)],
    "h_dim": [dict(h_dim=k) for k in (16, 32, 150)],
    "h_noise": [dict(h_noise=False), dict(h_noise=True)],
}
DEFAULT_ALGOS = {"layouts": ["fb", "bfb", "rfb"], "context": ["bfb", "rfb"], "kappa": ["rfb"],
                 "h_dim": ["bfb"], "h_noise": ["bfb", "rfb"]}
X = {"layouts": "n_train_layouts", "context": "context_len", "kappa": "kappa", "h_dim": "h_dim",
     "h_noise": "h_noise"}
TRANSITIONS = 1_000_000  # the paper's dataset size for the layout sweep


def points_of(which: str, values) -> list[dict]:
    """The swept points: SWEEPS[which], or one per value of --points."""
    if not values:
        return SWEEPS[which]
    field = X[which]
    if which == "layouts":
        return [dict(n_train_layouts=int(v)) for v in values]  # episodes set per env in main
    if which == "h_noise":
        return [dict(h_noise=v.lower() in ("1", "true")) for v in values]
    kind = float if which == "kappa" else int
    return [{field: kind(v)} for v in values]


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--which", required=True, choices=list(SWEEPS))
    p.add_argument("--env", default="fourrooms", choices=["fourrooms", "doors", "pointmass"])
    p.add_argument("--algos", nargs="+", default=None)
    p.add_argument("--seeds", type=int, default=3)
    p.add_argument("--runs-dir", default="runs")
    p.add_argument("--out", default="results")
    p.add_argument("--set", nargs="*", default=[], help="Config overrides for every point")
    p.add_argument("--size", default="cpu", choices=list(SIZES))
    p.add_argument("--points", nargs="+", default=None, help="the swept values (default: SWEEPS[which])")
    p.add_argument("--tag", default="", help="suffix of the run names and output files")
    a = p.parse_args()
    algos = a.algos or DEFAULT_ALGOS[a.which]
    points = points_of(a.which, a.points)
    if a.env == "doors" and a.which == "layouts":
        points = [pt for pt in points if pt["n_train_layouts"] <= 29]  # 49 layouts, 20 held out
    tag = f"-{a.tag}" if a.tag else ""

    cfgs = []  # build (and validate) every config before training anything
    for algo in algos:
        for pt in points:
            x = pt[X[a.which]]
            if a.which == "layouts" and (a.points or a.env == "pointmass"):
                # 1e6 transitions split over the layouts (the default points are the paper's
                # Four-Rooms datasets as listed, two of which hold 0.75e6)
                ep_len = Config.preset(a.env, algo, a.size).episode_len
                pt = dict(pt, episodes_per_layout=max(1, round(TRANSITIONS / (pt["n_train_layouts"] * ep_len))))
            # a point that *is* the preset reads back (or trains) the preset's own run
            preset = table.sweep_config(a.env, algo, a.size, a.seeds, a.runs_dir, a.set)
            is_preset = all(getattr(preset, k) == v for k, v in pt.items())
            cfg = preset if is_preset else table.sweep_config(
                a.env, algo, a.size, a.seeds, a.runs_dir, a.set,
                name=f"{a.env}-{algo}-{a.which}-{float(x):g}{tag}", **pt)
            cfgs.append((algo, x, cfg))

    rows = []
    for i, (algo, x, cfg) in enumerate(cfgs):
        res = table.results_of(cfg, f"[{i + 1}/{len(cfgs)}] {algo} {X[a.which]}={x}")
        rows.append({"algo": algo, "x": float(x), "train": res["train"], "test": res["test"],
                     "protocols": res.get("protocols", {}), "run": cfg.run_name,
                     "wall_time_s": res["wall_time_s"]["train"] + res["wall_time_s"]["eval"]})

    os.makedirs(a.out, exist_ok=True)
    stem = os.path.join(a.out, f"ablation_{a.which}_{a.env}{tag.replace('-', '_')}")
    with open(stem + ".json", "w") as f:
        json.dump({"which": a.which, "env": a.env, "size": a.size, "seeds": a.seeds, "overrides": a.set,
                   "measured": f"{time.strftime('%Y-%m-%d')} {table.commit_of()}", "rows": rows}, f, indent=2)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(9, 3.4), sharey=True)
    for ax, split in zip(axes, ("train", "test")):
        for algo in algos:
            pts = [r for r in rows if r["algo"] == algo]
            xs = [r["x"] for r in pts]
            m = [np.mean(r[split]) for r in pts]
            s = [np.std(r[split]) for r in pts]
            line = ax.errorbar(xs, m, yerr=s, marker="o", capsize=3, label=table.NAMES[algo])
            dense = [np.mean(r["protocols"]["dense"][split]) for r in pts if "dense" in r.get("protocols", {})]
            if len(dense) == len(pts):
                ax.plot(xs, dense, ls="--", marker=".", color=line[0].get_color(), alpha=0.6,
                        label=f"{table.NAMES[algo]} (dense)")
        ax.set_xlabel(X[a.which])
        if a.which in ("kappa", "layouts"):
            ax.set_xscale("log")
        ax.set_title(f"{a.env}: {split} layouts")
        ax.set_ylim(0, 1)
    axes[0].set_ylabel("success rate")
    axes[0].legend()
    fig.tight_layout()
    fig.savefig(stem + ".png", dpi=120)
    for r in rows:
        dense = r["protocols"].get("dense")
        extra = f"  dense {np.mean(dense['train']):.2f} / {np.mean(dense['test']):.2f}" if dense else ""
        print(f"{r['algo']:6s} {X[a.which]}={r['x']:<6g} train {np.mean(r['train']):.2f} +- {np.std(r['train']):.2f}  "
              f"test {np.mean(r['test']):.2f} +- {np.std(r['test']):.2f}{extra}  ({r['wall_time_s']:.0f} s)")
    print(f"wrote {stem}.json and {stem}.png")


if __name__ == "__main__":
    main()
