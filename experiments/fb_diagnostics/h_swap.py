"""Belief-FB with h_from="context": its F given the encoder's predicted wall map c(mu) of one
context episode (what it is evaluated with) against the same F given the layout's true map.

    python experiments/fb_diagnostics/h_swap.py runs/<run> [--context-lens 200 400 800]
        [--json results/fourrooms_h_swap.jsonl]

Evaluates the saved run on the paper and dense protocols, train and held-out layouts, with
the run's own evaluation keys (`zsbfm.evaluate`), twice: h = c(mu) (the run's own numbers)
and h = env.context_features(layout) (the walls oracle's input). The gap is what the one
episode's partial view of the layout costs F (experiments/fb_diagnostics/context_coverage.py).
--context-lens: c(mu) also of longer context episodes of the same behaviour policy (the
encoder pools any number of transitions), to see how much context closes the gap.
"""
from __future__ import annotations

import argparse
import dataclasses
import json

import jax.numpy as jnp
import numpy as np

import zsbfm
from zsbfm.agents import make_agent
from zsbfm.data.sources import make_env_for
from zsbfm.envs.gridworld import ACTION_DELTAS
from zsbfm.evaluate import protocol_score


def told_the_layout(agent):
    """The same agent, its context_h returning the layout's true context features."""
    class Told(type(agent)):
        def context_h(self, params, context):
            return self.env.context_features(context.layout)
    return Told(**{f.name: getattr(agent, f.name) for f in dataclasses.fields(agent)})


def revealed_map(agent):
    """The same agent, its h = what the context episode itself shows of the map: the true wall
    map on the cells the episode entered or bumped into, the train layouts' mean map elsewhere
    (the best an encoder of that episode could give cell by cell; context_coverage.py)."""
    prior = agent.layout_features.mean(0)
    size = agent.env.size

    class Revealed(type(agent)):
        def context_h(self, params, context):
            cells = jnp.round(context.obs).astype(jnp.int32)                   # [T+1, 2] (x, y)
            seen = jnp.zeros((size, size), bool).at[cells[:, 1], cells[:, 0]].set(True)
            stayed = jnp.all(cells[1:] == cells[:-1], axis=-1)
            bump = cells[:-1] + jnp.asarray(ACTION_DELTAS)[context.action]
            bump = jnp.where(stayed[:, None], bump, cells[:-1])                # moved: marks a visited cell
            seen = seen.at[bump[:, 1], bump[:, 0]].set(True)[1:-1, 1:-1].reshape(-1)
            return jnp.where(seen, self.env.context_features(context.layout), prior)
    return Revealed(**{f.name: getattr(agent, f.name) for f in dataclasses.fields(agent)})


def rounded(agent):
    """The same agent, its h = c(mu) rounded to a 0/1 map (the format F trained on with h_train_true)."""
    class Rounded(type(agent)):
        def context_h(self, params, context):
            return jnp.round(jnp.clip(super().context_h(params, context), 0.0, 1.0))
    return Rounded(**{f.name: getattr(agent, f.name) for f in dataclasses.fields(agent)})


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("run")
    p.add_argument("--protocols", nargs="+", default=["paper", "dense"])
    p.add_argument("--context-lens", nargs="*", type=int, default=[],
                   help="also evaluate h = c(mu) of context episodes of these lengths")
    p.add_argument("--json", default="")
    a = p.parse_args()
    run = zsbfm.load(a.run)
    if run.cfg.h_from != "context":
        raise SystemExit(f"{a.run}: h_from={run.cfg.h_from!r}, expected 'context' (F reads a wall map)")
    env = make_env_for(run.cfg, progress=False)
    agents = {"c(mu) of one episode": make_agent(run.cfg, env)}
    agents["true wall map"] = told_the_layout(agents["c(mu) of one episode"])
    if any(n <= 0 for n in a.context_lens):
        p.error(f"--context-lens must be positive integers, got {a.context_lens}")
    agents["c(mu) rounded to 0/1"] = rounded(agents["c(mu) of one episode"])
    agents["the episode's revealed map"] = revealed_map(agents["c(mu) of one episode"])
    variants = [(name, agent, None) for name, agent in agents.items()]
    for n in a.context_lens:
        variants += [(f"c(mu), {n}-step context", agents["c(mu) of one episode"], n),
                     (f"c(mu) rounded, {n}-step context", agents["c(mu) rounded to 0/1"], n),
                     (f"revealed map, {n}-step context", agents["the episode's revealed map"], n)]
    out = {"run": a.run}
    for name, agent, n in variants:
        for split in ("train", "test"):
            for protocol in a.protocols:
                score, valid = zsbfm.evaluate(run, split=split, protocol=protocol, agent=agent, context_len=n)
                v = float(np.mean(protocol_score(np.asarray(score), np.asarray(valid))))
                out[f"{name}/{split}/{protocol}"] = v
                print(f"h = {name:26s} {split:5s} {protocol:6s} {v:.2f}", flush=True)
    if a.json:
        with open(a.json, "a") as f:
            f.write(json.dumps(out) + "\n")


if __name__ == "__main__":
    main()
