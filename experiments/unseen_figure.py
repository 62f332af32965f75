"""Held-out success of F and encoder pairings, from eval_keys.py's JSON lines.

    python experiments/unseen_figure.py results/fourrooms_eval_keys.jsonl \\
        --group "FB" fb160-long-wide \\
        --group "true-map F, map encoder" ctxtrue160-k8-long-wide@ctxmlp160-k8-e96max-enc ... \\
        --bar FB=fb160-long-wide --out docs/figures/fourrooms_unseen_layouts.png

Each --group is a label and the pairings it holds, RUN or RUN@ENCODER, each with an optional
:READ and :K (run names: the last path component of eval_keys.py's "run" and "encoder_of";
READ and K its --context-read and --context-episodes, e.g. RUN@ENCODER:evidence or
RUN@ENCODER:evidence:1; none: the run's own). A group is drawn as its pairings'
means over draws (dots, with their standard error over draws) and, with several pairings,
their mean and its standard error over the pairings (a bar). --bar NAME=RUN draws RUN's
held-out mean as a dashed line and the same + 0.15 (the issue's bar) as a dotted one.
"""
from __future__ import annotations

import argparse
import json
import os

import numpy as np


def load(path: str) -> dict[tuple[str, str, str, str], dict]:
    """(run name, encoder run name or "", context_read or "", context_episodes or "") -> the
    last eval_keys.py row of that pairing."""
    rows = {}
    for line in open(path):
        row = json.loads(line)
        name = lambda p: os.path.basename(os.path.normpath(p)) if p else ""
        rows[(name(row["run"]), name(row.get("encoder_of") or ""), row.get("context_read", ""),
              str(row.get("context_episodes", "")))] = row
    return rows


def pairing(spec: str) -> tuple[str, str, str, str]:
    """RUN[@ENCODER][:READ[:K]] -> (RUN, ENCODER or "", READ or "", K or "")."""
    spec, _, rest = spec.partition(":")
    read, _, k = rest.partition(":")
    run, _, enc = spec.partition("@")
    return run, enc, read, k


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("jsonl")
    p.add_argument("--group", nargs="+", action="append", required=True, metavar=("LABEL", "RUN[@ENC]"))
    p.add_argument("--bar", default="", metavar="NAME=RUN", help="a baseline run: its mean and mean + 0.15")
    p.add_argument("--split", default="test", choices=["train", "test"])
    p.add_argument("--out", required=True)
    a = p.parse_args()
    rows = load(a.jsonl)
    for g in a.group:
        if len(g) < 2:
            p.error(f"--group needs a label and at least one RUN[@ENC], got {g}")
        missing = [s for s in g[1:] if pairing(s) not in rows]
        if missing:
            p.error(f"--group {g[0]!r}: no row of {a.jsonl} for {missing}")

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(1.1 * len(a.group) + 2.5, 3.6))
    for i, (label, *specs) in enumerate(a.group):
        draws = [np.asarray(rows[pairing(s)][a.split]) for s in specs]
        means = np.array([d.mean() for d in draws])
        ses = np.array([d.std(ddof=1) / np.sqrt(len(d)) if len(d) > 1 else 0.0 for d in draws])
        xs = i + np.linspace(-0.2, 0.2, len(means)) if len(means) > 1 else np.array([float(i)])
        if len(means) > 1:
            ax.bar(i, means.mean(), width=0.6, color="C0", alpha=0.25,
                   yerr=means.std(ddof=1) / np.sqrt(len(means)), capsize=4)
        ax.errorbar(xs, means, yerr=ses, fmt="o", color="C0", ms=4, capsize=2)
        ax.annotate(f"{means.mean():.3f}", (i, means.max() + ses.max() + 0.01), ha="center", fontsize=8)
    if a.bar:
        name, run = a.bar.split("=", 1)
        if pairing(run) not in rows:
            p.error(f"--bar: no row of {a.jsonl} for {run!r}")
        base = float(np.mean(rows[pairing(run)][a.split]))
        ax.axhline(base, color="grey", ls="--", lw=1, label=f"{name} {base:.3f}")
        ax.axhline(base + 0.15, color="k", ls=":", lw=1, label=f"{name} + 0.15")
        ax.legend(fontsize=8, loc="upper left")
    ax.set_xticks(range(len(a.group)), [g[0] for g in a.group], rotation=20, ha="right", fontsize=8)
    ax.set_ylabel(f"{'held-out' if a.split == 'test' else 'train'} success (paper protocol)")
    ax.set_ylim(0, None)
    fig.tight_layout()
    os.makedirs(os.path.dirname(a.out) or ".", exist_ok=True)
    fig.savefig(a.out, dpi=120)
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
