"""Ablations of the paper's Figure 2 and of Rotation-FB's kappa, with plots.

    python experiments/ablations.py --which layouts   # 10/20/30/50 train layouts (Fig. 2 left)
    python experiments/ablations.py --which context   # context length 25/50/100 (Fig. 2 right)
    python experiments/ablations.py --which kappa     # Rotation-FB kappa 1/10/50/100/200
    python experiments/ablations.py --which kappa --set steps=6000   # shortened

Each point is an ordinary `zsbfm.train` run (3 vmapped seeds, CPU preset) named
<env>-<algo>-<which>-<value>, so a killed sweep resumes and finished points are read back;
a point equal to the preset (20 layouts, context 100, kappa 50 on fourrooms) is the
preset's own run, shared with `make table`.
Writes results/ablation_<which>_<env>.json and .png (success vs the swept value, train and
test, mean +- std over seeds).

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

import numpy as np

import table  # experiments/table.py: configs, read-back and resume of finished runs

SWEEPS = {
    "layouts": [dict(n_train_layouts=n, episodes_per_layout=e) for n, e in ((10, 1000), (20, 500), (30, 250), (50, 150))],
    "context": [dict(context_len=n) for n in (25, 50, 100)],
    "kappa": [dict(kappa=float(k)) for k in (1, 10, 50, 100, 200)],
}
DEFAULT_ALGOS = {"layouts": ["fb", "bfb", "rfb"], "context": ["bfb", "rfb"], "kappa": ["rfb"]}
X = {"layouts": "n_train_layouts", "context": "context_len", "kappa": "kappa"}


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--which", required=True, choices=list(SWEEPS))
    p.add_argument("--env", default="fourrooms", choices=["fourrooms", "doors", "pointmass"])
    p.add_argument("--algos", nargs="+", default=None)
    p.add_argument("--seeds", type=int, default=3)
    p.add_argument("--runs-dir", default="runs")
    p.add_argument("--out", default="results")
    p.add_argument("--set", nargs="*", default=[], help="Config overrides for every point")
    a = p.parse_args()
    algos = a.algos or DEFAULT_ALGOS[a.which]
    points = SWEEPS[a.which]
    if a.env == "doors" and a.which == "layouts":
        points = [pt for pt in points if pt["n_train_layouts"] <= 29]  # 49 layouts, 20 held out

    cfgs = []  # build (and validate) every config before training anything
    for algo in algos:
        for pt in points:
            x = pt[X[a.which]]
            if a.which == "layouts" and a.env == "pointmass":  # 1e6 transitions of 250 steps
                pt = dict(pt, episodes_per_layout=round(1_000_000 / (pt["n_train_layouts"] * 250)))
            # a point that *is* the preset reads back (or trains) the preset's own run
            preset = table.sweep_config(a.env, algo, "cpu", a.seeds, a.runs_dir, a.set)
            is_preset = all(getattr(preset, k) == v for k, v in pt.items())
            cfg = preset if is_preset else table.sweep_config(
                a.env, algo, "cpu", a.seeds, a.runs_dir, a.set, name=f"{a.env}-{algo}-{a.which}-{x:g}", **pt)
            cfgs.append((algo, x, cfg))

    rows = []
    for i, (algo, x, cfg) in enumerate(cfgs):
        res = table.results_of(cfg, f"[{i + 1}/{len(cfgs)}] {algo} {X[a.which]}={x:g}")
        rows.append({"algo": algo, "x": x, "train": res["train"], "test": res["test"],
                     "wall_time_s": res["wall_time_s"]["train"] + res["wall_time_s"]["eval"]})

    os.makedirs(a.out, exist_ok=True)
    stem = os.path.join(a.out, f"ablation_{a.which}_{a.env}")
    with open(stem + ".json", "w") as f:
        json.dump({"which": a.which, "env": a.env, "overrides": a.set, "rows": rows}, f, indent=2)

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
            ax.errorbar(xs, m, yerr=s, marker="o", capsize=3, label=table.NAMES[algo])
        ax.set_xlabel(X[a.which])
        if a.which == "kappa":
            ax.set_xscale("log")
        ax.set_title(f"{a.env}: {split} layouts")
        ax.set_ylim(0, 1)
    axes[0].set_ylabel("success rate")
    axes[0].legend()
    fig.tight_layout()
    fig.savefig(stem + ".png", dpi=120)
    for r in rows:
        print(f"{r['algo']:6s} {X[a.which]}={r['x']:<6g} train {np.mean(r['train']):.2f} +- {np.std(r['train']):.2f}  "
              f"test {np.mean(r['test']):.2f} +- {np.std(r['test']):.2f}  ({r['wall_time_s']:.0f} s)")
    print(f"wrote {stem}.json and {stem}.png")


if __name__ == "__main__":
    main()
