"""Held-out layouts against the number of train layouts: several ablation sweeps in one figure.

    python experiments/transfer_figure.py \\
        results/ablation_layouts_fourrooms_recipe.json:Belief-FB \\
        "results/ablation_layouts_fourrooms_walls.json:Oracle (walls)" \\
        --probe results/fourrooms_encoder_probe.jsonl --random 0.16 0.30 \\
        --out docs/figures/fourrooms_transfer_layouts.png

Each argument is a JSON written by experiments/ablations.py (--which layouts) and its label.
Panels: the paper protocol and the dense one, on train and on held-out test layouts, against
the number of train layouts (mean over seeds; one seed: the point itself). --random draws a
random policy's test score (paper, dense) as a grey line. --probe adds a panel of the encoder
probe's balanced accuracy on the walls that vary between unseen layouts
(experiments/fb_diagnostics/encoder_probe.py --json), one point per n_train_layouts it holds.
"""

from __future__ import annotations

import argparse
import json

import numpy as np


def probe_points(path: str) -> tuple[list[int], list[float]]:
    """(n_train_layouts, unseen varying-wall balanced accuracy) of each Four-Rooms probe line
    run at the preset's encoder (only n_train_layouts / episodes_per_layout set)."""
    pts = {}
    for line in open(path):
        row = json.loads(line)
        sets = dict(s.split("=", 1) for s in row.get("set", []))
        if row.get("env") != "fourrooms" or set(sets) - {"n_train_layouts", "episodes_per_layout"}:
            continue
        pts[int(sets.get("n_train_layouts", 10))] = row["test_varying_cell_balanced_accuracy"]
    xs = sorted(pts)
    return xs, [pts[x] for x in xs]


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("sweeps", nargs="+", help="PATH:LABEL of an ablations.py --which layouts JSON")
    p.add_argument("--probe", default="", help="encoder_probe.py's --json file")
    p.add_argument("--random", nargs=2, type=float, default=None, metavar=("PAPER", "DENSE"),
                   help="a random policy's test score on the paper and dense protocols")
    p.add_argument("--out", required=True)
    a = p.parse_args()

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = [("paper", "train"), ("paper", "test"), ("dense", "train"), ("dense", "test")]
    fig, axes = plt.subplots(1, len(panels) + bool(a.probe), figsize=(3.2 * (len(panels) + bool(a.probe)), 3.2))
    for spec in a.sweeps:
        path, label = spec.split(":", 1)
        rows = json.load(open(path))["rows"]
        rows = sorted(rows, key=lambda r: r["x"])
        xs = [r["x"] for r in rows]
        for ax, (proto, split) in zip(axes, panels):
            ys = [np.mean(r[split] if proto == "paper" else r["protocols"][proto][split]) for r in rows]
            ax.plot(xs, ys, marker="o", label=label)
    for ax, (proto, split) in zip(axes, panels):
        if a.random and split == "test":
            ax.axhline(a.random[0 if proto == "paper" else 1], color="grey", ls=":", label="random policy")
        ax.set_xscale("log")
        ax.set_xticks(xs, [f"{x:g}" for x in xs])
        ax.set_ylim(0, 1)
        ax.set_xlabel("train layouts (1e6 transitions in all)")
        ax.set_title(f"{proto} protocol, {split} layouts", fontsize=9)
    axes[0].set_ylabel("success rate")
    axes[1].legend(fontsize=7)
    if a.probe:
        ax = axes[-1]
        px, py = probe_points(a.probe)
        ax.plot(px, py, marker="s", color="k")
        ax.axhline(0.5, color="grey", ls=":")
        ax.set_xscale("log")
        ax.set_xticks(px, [str(x) for x in px])
        ax.set_ylim(0.4, 1)
        ax.set_xlabel("train layouts")
        ax.set_title("encoder: unseen walls\n(balanced accuracy, 0.5 = chance)", fontsize=9)
    fig.tight_layout()
    fig.savefig(a.out, dpi=120)
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
