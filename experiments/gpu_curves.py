"""Learning curves of experiments/gpu_check.py summaries, against FB updates.

    python experiments/gpu_curves.py results/gpu/h200_authors_*.json --out docs/figures/authors_h200.png \\
        --ref "authors' Belief-FB:20000=0.73"

One line per check (mean over its seeds; the band: min to max) of the paper protocol on
train layouts (solid) and test layouts (dashed), against FB updates: a belief check's
encoder steps are not counted. The twin heads' gap E|M1 - M2| goes on a second panel where
the rows hold it. --ref adds recorded points ("label:updates=score,...", train layouts).
"""

from __future__ import annotations

import argparse
import json

import numpy as np


def curves(path: str):
    """(label, fb_updates, train per seed, test mean, head gap) for each check of one summary."""
    out = json.load(open(path))
    for r in out["results"]:
        rows = [row for row in r["curve"] if row["updates"] > r["encoder_steps"]]
        label = f"{r['algo']} {r['config']}" + (f" {' '.join(r.get('overrides', []))}" if r.get("overrides") else "")
        yield (label, np.array([row["updates"] - r["encoder_steps"] for row in rows]),
               np.array([row["train/paper_per_seed"] for row in rows]),
               np.array([row["test/paper"] for row in rows]),
               np.array([row.get("M_head_gap", np.nan) for row in rows]))


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("summaries", nargs="+", help="gpu_check.py --out JSON files")
    p.add_argument("--out", required=True, help="the PNG")
    p.add_argument("--ref", nargs="*", default=[], help='recorded points, "label:20000=0.73,40000=0.8"')
    p.add_argument("--title", default="")
    a = p.parse_args()

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, gap_ax) = plt.subplots(1, 2, figsize=(11, 4))
    for path in a.summaries:
        for label, x, train, test, gap in curves(path):
            line, = ax.plot(x, train.mean(1), label=f"{label} (train)")
            ax.fill_between(x, train.min(1), train.max(1), color=line.get_color(), alpha=0.15)
            ax.plot(x, test, "--", color=line.get_color(), label=f"{label} (test)")
            if np.isfinite(gap).any():
                gap_ax.plot(x, gap, color=line.get_color(), label=label)
    for ref in a.ref:
        label, points = ref.split(":", 1)
        xy = [tuple(map(float, pt.split("="))) for pt in points.split(",")]
        ax.scatter(*zip(*xy), marker="*", s=120, color="k", zorder=3, label=label)
    ax.set(xlabel="FB updates", ylabel="success (paper protocol)", ylim=(0, 1), title=a.title or "Four-Rooms")
    ax.legend(fontsize=7)
    gap_ax.set(xlabel="FB updates", ylabel="E|M1 - M2| (twin heads' gap)", title="head gap")
    gap_ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(a.out, dpi=120)
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
