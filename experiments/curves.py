"""Learning curves of several runs side by side, against FB updates and against FLOPs.

    python experiments/curves.py runs/a runs/b --labels "batch 256" "batch 1024" \\
        --out docs/figures/recipe_batch.png --md results/recipe_batch.md [--target 0.70]

Reads each run's metrics.jsonl (runs trained with eval_every > 0; a run still training is
read as far as it got), plots the mean over seeds (the band: min to max) of the paper
protocol on train and test layouts, and of the dense protocol on train layouts, against FB
updates (encoder pre-training steps not counted) and against cumulative FLOPs per seed
(XLA's cost analysis, encoder phase included). --ref adds a recorded curve as points
("label:updates=score,updates=score"). The Markdown table gives, per run, the score at each
evaluation, the first FLOPs per seed at which the mean train score reaches --target, and the
train score averaged over the last --last evaluations (a steadier end point than the last
evaluation alone: each seed's mean over those evaluations, then mean +- standard error over
seeds).
"""

from __future__ import annotations

import argparse
import json
import os

import numpy as np

from zsbfm.config import Config
from zsbfm.evaluate import standard_error
from zsbfm.plots import curve_arrays

PANELS = (("train/paper", "paper protocol, train layouts"), ("test/paper", "paper protocol, test layouts"),
          ("train/dense", "dense protocol, train layouts"))


def read(run_dir: str) -> dict:
    with open(os.path.join(run_dir, "config.json")) as f:
        cfg = Config.from_dict(json.load(f))
    with open(os.path.join(run_dir, "metrics.jsonl")) as f:
        rows = [json.loads(line) for line in f if line.strip()]
    steps, flops, scores = curve_arrays(rows)
    keep = steps > cfg.steps - cfg.fb_steps  # points of the FB phase (an encoder-phase policy is untrained)
    return {"cfg": cfg, "updates": steps[keep] - (cfg.steps - cfg.fb_steps), "flops": flops[keep],
            "scores": {k: v[keep] for k, v in scores.items()}}


def parse_ref(text: str):
    label, points = text.split(":", 1)
    xs, ys = zip(*[(float(p.split("=")[0]), float(p.split("=")[1])) for p in points.split(",")])
    return label, np.asarray(xs), np.asarray(ys)


def first_reach(curve: dict, key: str, target: float) -> float | None:
    mean = curve["scores"][key].mean(1)
    hit = np.nonzero(mean >= target)[0]
    return float(curve["flops"][hit[0]]) if len(hit) else None


def last_mean(curve: dict, key: str, k: int) -> tuple[float, float, np.ndarray]:
    """Mean over seeds of each seed's mean over the last k evaluations of `key`, its standard
    error over seeds (0 for one seed), and the per-seed means [S]."""
    per_seed = curve["scores"][key][-k:].mean(0)  # [T, S] -> [S]
    se = float(standard_error(per_seed)) if per_seed.shape[0] > 1 else 0.0
    return float(per_seed.mean()), se, per_seed


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("runs", nargs="+")
    p.add_argument("--labels", nargs="+", default=None)
    p.add_argument("--out", required=True, help="the PNG")
    p.add_argument("--md", default="", help="also write the table here")
    p.add_argument("--target", type=float, default=0.70)
    p.add_argument("--ref", nargs="*", default=[], help='recorded curves, "label:20000=0.73,40000=0.8" (train, paper)')
    p.add_argument("--title", default="")
    p.add_argument("--last", type=int, default=4, help="evaluations averaged for the steadier end point")
    a = p.parse_args()
    if a.last < 1:
        raise SystemExit(f"--last {a.last}: must be >= 1")
    labels = a.labels or [os.path.basename(r.rstrip("/")) for r in a.runs]
    if len(labels) != len(a.runs):
        raise SystemExit(f"--labels: {len(labels)} labels for {len(a.runs)} runs")
    curves = [read(r) for r in a.runs]

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, len(PANELS), figsize=(4.2 * len(PANELS), 6.4), squeeze=False)
    for c, label in zip(curves, labels):
        for j, (key, title) in enumerate(PANELS):
            if key not in c["scores"]:
                continue
            s = c["scores"][key]
            for i, x in enumerate((c["updates"], c["flops"] / 1e12)):
                line, = axes[i, j].plot(x, s.mean(1), marker=".", label=f"{label} ({s.shape[1]} seeds)")
                if s.shape[1] > 1:
                    axes[i, j].fill_between(x, s.min(1), s.max(1), color=line.get_color(), alpha=0.2)
    for label, xs, ys in (parse_ref(r) for r in a.ref):
        axes[0, 0].scatter(xs, ys, marker="*", s=90, color="k", zorder=3, label=label)
    for j, (key, title) in enumerate(PANELS):
        axes[0, j].set_title(title, fontsize=9)
        axes[0, j].set_xlabel("FB updates")
        axes[1, j].set_xlabel("TFLOP per seed (encoder phase included)")
        for i in range(2):
            axes[i, j].set_ylim(0, 1)
            axes[i, j].axhline(a.target, color="grey", lw=0.5, ls=":")
    axes[0, 0].set_ylabel("success")
    axes[1, 0].set_ylabel("success")
    axes[0, 0].legend(fontsize=7, loc="upper left")
    if a.title:
        fig.suptitle(a.title, fontsize=10)
    fig.tight_layout()
    os.makedirs(os.path.dirname(os.path.abspath(a.out)), exist_ok=True)
    fig.savefig(a.out, dpi=110)
    plt.close(fig)

    lines = [f"| run | seeds | FB updates: train / test (paper protocol, mean over seeds) | TFLOP per seed to reach {a.target:.2f} on train "
             f"| train, mean of the last {a.last} evaluations (seeds) |",
             "|---|---|---|---|---|"]
    for c, label, run in zip(curves, labels, a.runs):
        tr, te = c["scores"]["train/paper"].mean(1), c["scores"]["test/paper"].mean(1)
        pts = ", ".join(f"{u / 1000:.0f}k {x:.2f} / {y:.2f}" for u, x, y in zip(c["updates"], tr, te))
        reach = first_reach(c, "train/paper", a.target)
        mean, se, per_seed = last_mean(c, "train/paper", a.last)
        span = f"{c['updates'][-min(a.last, len(c['updates']))] / 1000:.0f}k-{c['updates'][-1] / 1000:.0f}k"
        lines.append(f"| {label} (`{run}`) | {c['scores']['train/paper'].shape[1]} | {pts} | "
                     f"{'not reached' if reach is None else f'{reach / 1e12:.0f}'} | "
                     f"{mean:.2f} +- {se:.2f} over {span} ({' / '.join(f'{v:.2f}' for v in per_seed)}) |")
    table = "\n".join(lines)
    print(table)
    if a.md:
        with open(a.md, "w") as f:
            f.write(table + "\n")


if __name__ == "__main__":
    main()
