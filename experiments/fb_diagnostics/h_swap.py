"""Belief-FB with h_from="context": its F given the encoder's predicted wall map c(mu) of one
context episode (what it is evaluated with) against the same F given the layout's true map.

    python experiments/fb_diagnostics/h_swap.py runs/<run> [--json results/h_swap.json]

Evaluates the saved run on the paper and dense protocols, train and held-out layouts, with
the run's own evaluation keys (`zsbfm.evaluate`), twice: h = c(mu) (the run's own numbers)
and h = env.context_features(layout) (the walls oracle's input). The gap is what the one
episode's partial view of the layout costs F (experiments/fb_diagnostics/context_coverage.py).
"""
from __future__ import annotations

import argparse
import dataclasses
import json

import numpy as np

import zsbfm
from zsbfm.agents import make_agent
from zsbfm.data.sources import make_env_for
from zsbfm.evaluate import protocol_score


def told_the_layout(agent):
    """The same agent, its context_h returning the layout's true context features."""
    class Told(type(agent)):
        def context_h(self, params, context):
            return self.env.context_features(context.layout)
    return Told(**{f.name: getattr(agent, f.name) for f in dataclasses.fields(agent)})


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("run")
    p.add_argument("--protocols", nargs="+", default=["paper", "dense"])
    p.add_argument("--json", default="")
    a = p.parse_args()
    run = zsbfm.load(a.run)
    if run.cfg.h_from != "context":
        raise SystemExit(f"{a.run}: h_from={run.cfg.h_from!r}, expected 'context' (F reads a wall map)")
    env = make_env_for(run.cfg, progress=False)
    agents = {"c(mu) of one episode": make_agent(run.cfg, env)}
    agents["true wall map"] = told_the_layout(agents["c(mu) of one episode"])
    out = {"run": a.run}
    for name, agent in agents.items():
        for split in ("train", "test"):
            for protocol in a.protocols:
                score, valid = zsbfm.evaluate(run, split=split, protocol=protocol, agent=agent)
                v = float(np.mean(protocol_score(np.asarray(score), np.asarray(valid))))
                out[f"{name}/{split}/{protocol}"] = v
                print(f"h = {name:22s} {split:5s} {protocol:6s} {v:.2f}")
    if a.json:
        with open(a.json, "a") as f:
            f.write(json.dumps(out) + "\n")


if __name__ == "__main__":
    main()
