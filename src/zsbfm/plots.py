"""Plots of a run: training curves, success per split and seed, value maps with policies."""

from __future__ import annotations

import os

import jax
import jax.numpy as jnp
import numpy as np


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_metrics(run, path):
    """One panel per logged metric against gradient steps, one line per seed."""
    plt = _plt()
    rows = run.metrics
    keys = [k for k in rows[0] if k not in ("chunk", "step", "seconds")] if rows else []
    if not keys:
        return None
    cols = min(4, len(keys))
    nrows = -(-len(keys) // cols)
    fig, axes = plt.subplots(nrows, cols, figsize=(3.6 * cols, 2.8 * nrows), squeeze=False)
    steps = [r["step"] for r in rows]
    for ax, k in zip(axes.flat, keys):
        ax.plot(steps, np.asarray([r[k] for r in rows]))
        ax.set_title(k, fontsize=9)
        ax.set_xlabel("step", fontsize=8)
    for ax in axes.flat[len(keys):]:
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def plot_success(run, path):
    """Mean +- std over seeds of the success rate (or return) on train and test contexts."""
    plt = _plt()
    splits = ("train", "test")
    vals = [np.asarray(run.results[s]) for s in splits]
    fig, ax = plt.subplots(figsize=(3.6, 3.0))
    ax.bar(splits, [v.mean() for v in vals], yerr=[v.std() for v in vals], capsize=4,
           color=["tab:blue", "tab:orange"])
    for i, v in enumerate(vals):
        ax.scatter([i] * len(v), v, color="k", s=10, zorder=3)
    if run.results.get("metric", "success") == "return":
        ax.set_ylabel("episode return")
    else:
        ax.set_ylim(0, 1)
        ax.set_ylabel("success rate")
    ax.set_title(f"{run.cfg.env} {run.cfg.algo} ({len(vals[0])} seeds)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def value_map(agent, env, params, ctx, goal, key):
    """V(s) = max_a Q(s, a) and the greedy action on every cell, for z from `goal`.

    Returns (values float[H, W], actions int[H, W]) for one parameter set.
    """
    from zsbfm.evaluate import context_episode

    size = env.size
    ys, xs = jnp.mgrid[0:size, 0:size]
    cells = jnp.stack([xs.reshape(-1), ys.reshape(-1)], -1).astype(jnp.float32)
    context = context_episode(env, key, ctx, agent.cfg.context_len)
    task = agent.goal_task(params, goal, context)
    q = agent.q_values(params, cells, jax.tree_util.tree_map(
        lambda x: jnp.broadcast_to(x, (cells.shape[0],) + x.shape), task))
    return q.max(-1).reshape(size, size), q.argmax(-1).reshape(size, size)


def plot_value_maps(run, path, seed: int = 0, goal_index: int = 0):
    """Value maps and greedy arrows of one seed on the first train and test layout."""
    from zsbfm.agents import make_agent
    from zsbfm.envs import index_contexts, make_env
    from zsbfm.envs.render import render_layouts

    cfg = run.cfg
    env = make_env(cfg.env, n_train=cfg.n_train_layouts, episode_len=cfg.episode_len)
    agent = make_agent(cfg, env)
    if not hasattr(env, "size") or not hasattr(agent, "q_values") or not env.discrete:
        return None  # value maps are drawn for gridworld agents with Q-values
    params = run.seed_params(seed)
    panels = []
    for split in ("train", "test"):
        ctx = index_contexts(env.contexts(split), 0)
        goal = env.eval_goals(ctx)[goal_index]
        v, a = value_map(agent, env, params, ctx, goal, jax.random.PRNGKey(0))
        panels.append(dict(walls=np.asarray(ctx.walls), values=np.asarray(v), actions=np.asarray(a),
                           start=tuple(np.asarray(env.eval_start(ctx)).astype(int)),
                           goals=[tuple(np.asarray(goal).astype(int))],
                           title=f"{cfg.algo} {split} layout 0, seed {seed}"))
    return render_layouts(path, panels)


def plot_run(run, run_dir):
    """Write every plot of a run into its directory."""
    plot_metrics(run, os.path.join(run_dir, "metrics.png"))
    plot_success(run, os.path.join(run_dir, "success.png"))
    plot_value_maps(run, os.path.join(run_dir, "value_maps.png"))
