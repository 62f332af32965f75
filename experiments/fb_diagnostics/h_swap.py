"""Belief-FB with h_from="context": its F given the encoder's predicted wall map c(mu) of one
context episode (what it is evaluated with) against the same F given the layout's true map.

    python experiments/fb_diagnostics/h_swap.py runs/<run> [--context-lens 200 400 800]
        [--context-episodes 1 2 4 8 16] [--json results/fourrooms_h_swap.jsonl]

Evaluates the saved run on the paper and dense protocols, train and held-out layouts, with
the run's own evaluation keys (`zsbfm.evaluate`), twice: h = c(mu) (the run's own numbers)
and h = env.context_features(layout) (the walls oracle's input). The gap is what the one
episode's partial view of the layout costs F (experiments/fb_diagnostics/context_coverage.py).
--context-lens: c(mu) also of longer context episodes of the same behaviour policy (the
encoder pools any number of transitions), to see how much context closes the gap.
--context-episodes: c(mu) (and the revealed map) of contexts of K independent episodes
(Config.context_episodes; the run's own K is what it was trained and evaluated with).
Beside each success rate, the map error of that h on the split's layouts: the mean
|h - true map| over the cells that differ between layouts (--map-contexts fresh contexts per
layout; 0 for the true map).
--encoder-of RUN_B: the same, with RUN_B's encoder and context head in place of the run's. With
h_train_true F never reads the encoder (it trains on the true maps), so a run that stops right
after its encoder phase (`--set steps=<enc_steps + chunk_steps>`) can be scored with the F of a
full run of the same settings: an encoder variant at the cost of its encoder phase alone. The
two configs may differ only in the encoder's fields, its seed and its train layouts
(ENCODER_FIELDS; with other train layouts, "train" means RUN_B's).
--context-read evidence: h read off the context as Config.context_read="evidence" (the
evidence pool's wall fraction on the cells the context shows, c(mu) elsewhere) in place of the
run's own read; the parameters are the same (an encoder with enc_pool="evidence").
"""
from __future__ import annotations

import argparse
import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np

import zsbfm
from zsbfm.agents import make_agent
from zsbfm.data.sources import make_env_for
from zsbfm.evaluate import context_episode, protocol_score
from zsbfm.names import CONTEXT_READS

from context_coverage import varying_cells  # this script's folder is on sys.path


def with_context_h(agent, fn):
    """The same agent over the same parameters, its context_h(params, context) replaced by
    fn(agent, params, context) (agent: the original, so fn may call its own context_h)."""
    swapped = type(type(agent).__name__, (type(agent),),
                   {"context_h": lambda self, params, context: fn(agent, params, context)})
    return swapped(**{f.name: getattr(agent, f.name) for f in dataclasses.fields(agent)})


def true_map(agent, params, context):
    """The layout's true context features (the walls oracle's input)."""
    return agent.env.context_features(context.layout)


def rounded(agent, params, context):
    """c(mu) rounded to a 0/1 map (the format F trained on with h_train_true)."""
    return jnp.round(jnp.clip(agent.context_h(params, context), 0.0, 1.0))


def revealed_map(agent, params, context):
    """What the context episode itself shows of the map: the true wall map on the cells it
    entered or bumped into (env.revealed_features; of K episodes, the union), the train
    layouts' mean map elsewhere (the best an encoder of that episode could give cell by cell)."""
    obs = context.obs
    seen = agent.env.revealed_features(obs[..., :-1, :], context.action, obs[..., 1:, :])
    return jnp.where(seen, agent.env.context_features(context.layout), agent.layout_features.mean(0))


def per_layout(env, split: str, n: int, key, fn, batch: int = 20):
    """fn(key, layout) for n fresh keys per layout of the split, jitted: [n_layouts, n, ...];
    `batch` layouts at a time (all 640 layouts' contexts at once do not fit in 24 GiB)."""
    layouts = env.contexts(split)
    n_layouts = len(np.asarray(layouts.walls))
    keys = jax.random.split(key, n_layouts * n).reshape(n_layouts, n, -1)
    one_layout = lambda args: jax.vmap(lambda k: fn(k, args[1]))(args[0])
    return jax.jit(lambda ks, lays: jax.lax.map(one_layout, (ks, lays), batch_size=batch))(keys, layouts)


def map_error(agent, params, env, varies, split: str, context_len: int, episodes: int, n: int,
              seed: int = 0) -> float:
    """Mean |h - true map| over the varying cells (varies: bool[(size - 2)^2], True where a
    cell varies; `varying_cells`' interior), n fresh contexts per layout."""
    def one(key, layout):
        h = agent.context_h(params, context_episode(env, key, layout, context_len, episodes))
        return jnp.sum(jnp.abs(h - env.context_features(layout)) * varies) / jnp.sum(varies)

    return float(np.mean(per_layout(env, split, n, jax.random.PRNGKey(seed), one)))


# what --encoder-of lets differ between the two runs: the encoder phase, the run's length, the
# seed (an encoder trained from another seed, on that seed's data: its spread over one F), and
# the encoder's train layouts (DATA_FIELDS: an encoder that read more layouts than F did)
DATA_FIELDS = {"n_train_layouts", "episodes_per_layout"}
ENCODER_FIELDS = DATA_FIELDS | {
    "seed", "enc_embed", "enc_heads", "enc_layers", "enc_mlp", "pred_hidden", "enc_lr", "enc_beta",
    "enc_contrast", "enc_cell_tokens", "enc_pool", "enc_pool_width", "enc_steps", "enc_batch", "enc_target", "h_dim",
    "enc_context_coef", "context_head_hidden", "context_loss", "context_target", "context_episodes",
    "name", "steps", "eval_every", "chunk_steps",
    "h_train_mask",  # F's training input only: evaluation never reads it, so F's run may differ there too
    "context_read"}


def with_encoder_of(run, path: str):
    """`run` (its F and B) with the encoder and context head of the run at `path`, under that
    run's config (module docstring, --encoder-of)."""
    other = zsbfm.load(path)
    if not (run.cfg.h_train_true and other.cfg.h_train_true):
        raise SystemExit(f"--encoder-of needs h_train_true=True in both runs (F must not read the encoder), got "
                         f"{run.cfg.h_train_true} and {other.cfg.h_train_true}")
    a, b = dataclasses.asdict(run.cfg), dataclasses.asdict(other.cfg)
    differ = sorted(k for k in a if a[k] != b[k])
    if set(differ) - ENCODER_FIELDS:
        raise SystemExit(f"--encoder-of {path}: its config differs in {sorted(set(differ) - ENCODER_FIELDS)}, "
                         f"allowed: only {sorted(ENCODER_FIELDS)}")
    print(f"F and B of the run, encoder of {path} (differs in: {', '.join(differ)})")
    if set(differ) & DATA_FIELDS:
        print(f"  the encoder trained on other layouts ({', '.join(sorted(set(differ) & DATA_FIELDS))}): 'train' "
              f"below is {path}'s train layouts, which F may not have seen; the held-out ('test') layouts are "
              f"the family's fixed ones either way")
    return dataclasses.replace(other, params=run.params.replace(enc=other.params.enc))


def with_read(run, read: str):
    """`run` with Config.context_read=`read` (how h is read off a context; the same parameters),
    or `run` itself for read=""."""
    if not read or read == run.cfg.context_read:
        return run
    print(f"h read off the context as context_read={read!r} (the run's own: {run.cfg.context_read!r})")
    return dataclasses.replace(run, cfg=dataclasses.replace(run.cfg, context_read=read))


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("run")
    p.add_argument("--protocols", nargs="+", default=["paper", "dense"])
    p.add_argument("--context-lens", nargs="*", type=int, default=[],
                   help="also evaluate h = c(mu) of context episodes of these lengths")
    p.add_argument("--context-episodes", nargs="*", type=int, default=[],
                   help="also evaluate with contexts of this many episodes (of the run's context_len)")
    p.add_argument("--map-contexts", type=int, default=8, help="fresh contexts per layout for the map error")
    p.add_argument("--encoder-of", default="", metavar="RUN_B",
                   help="score with RUN_B's encoder and head (both runs h_train_true)")
    p.add_argument("--context-read", default="", choices=["", *CONTEXT_READS],
                   help="read h off the context this way (Config.context_read) instead of the run's own")
    p.add_argument("--json", default="")
    a = p.parse_args()
    run = zsbfm.load(a.run)
    if a.encoder_of:
        run = with_encoder_of(run, a.encoder_of)
    run = with_read(run, a.context_read)
    if run.cfg.h_from != "context":
        raise SystemExit(f"{a.run}: h_from={run.cfg.h_from!r}, expected 'context' (F reads a wall map)")
    env = make_env_for(run.cfg, progress=False)
    if any(n <= 0 for n in a.context_lens + a.context_episodes):
        p.error(f"--context-lens and --context-episodes must be positive integers, got "
                f"{a.context_lens}, {a.context_episodes}")
    own = make_agent(run.cfg, env)
    agents = {"c(mu) of one episode": own, "true wall map": with_context_h(own, true_map),
              "c(mu) rounded to 0/1": with_context_h(own, rounded),
              "the episode's revealed map": with_context_h(own, revealed_map)}
    K = run.cfg.context_episodes
    if K > 1:  # the run's own context is K episodes
        agents = {name.replace("one episode", f"{K} episodes").replace("the episode's", f"{K} episodes'"): agent
                  for name, agent in agents.items()}
    h_name = "evidence + c(mu)" if run.cfg.context_read == "evidence" else "c(mu)"  # what h is read from
    agents = {name.replace("c(mu)", h_name): agent for name, agent in agents.items()}
    own_name, rounded_name, revealed_name = (name for name in agents if name != "true wall map")
    variants = [(name, agent, None, None) for name, agent in agents.items()]
    for n in a.context_lens:
        variants += [(f"{h_name}, {n}-step context", agents[own_name], n, None),
                     (f"{h_name} rounded, {n}-step context", agents[rounded_name], n, None),
                     (f"revealed map, {n}-step context", agents[revealed_name], n, None)]
    for k in a.context_episodes:
        variants += [(f"{h_name}, {k}-episode context", agents[own_name], None, k),
                     (f"revealed map, {k}-episode context", agents[revealed_name], None, k)]
    out = {"run": a.run, **({"encoder_of": a.encoder_of} if a.encoder_of else {}),
           **({"context_read": run.cfg.context_read} if run.cfg.context_read != "head" else {})}
    params0 = jax.tree_util.tree_map(lambda x: x[0], run.params)  # seed 0
    varies = jnp.asarray(varying_cells(env)[1:-1, 1:-1].reshape(-1))
    for name, agent, n, k in variants:
        for split in ("train", "test"):
            err = map_error(agent, params0, env, varies, split, n or run.cfg.context_len, k or K, a.map_contexts)
            out[f"{name}/{split}/map_error"] = err
            for protocol in a.protocols:
                score, valid = zsbfm.evaluate(run, split=split, protocol=protocol, agent=agent, context_len=n,
                                              context_episodes=k)
                v = float(np.mean(protocol_score(np.asarray(score), np.asarray(valid))))
                out[f"{name}/{split}/{protocol}"] = v
                print(f"h = {name:30s} {split:5s} {protocol:6s} {v:.2f}   map error {err:.3f}", flush=True)
    if a.json:
        with open(a.json, "a") as f:
            f.write(json.dumps(out) + "\n")


if __name__ == "__main__":
    main()
