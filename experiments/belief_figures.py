"""Figures of the belief methods (paper Figures 8 and 9) from trained runs.

    python experiments/belief_figures.py --env fourrooms --runs-dir runs --out results/figures

Reads runs/<env>-{fb,bfb,rfb}-cpu (or --fb/--bfb/--rfb paths) and writes:
  h_pca_<env>.png        2-D PCA of h = mu(episode) for episodes of 5 train and 5 test
                         layouts, coloured by layout (Figure 9), with a separation score;
  q_maps_<env>.png       value maps and greedy arrows of FB, BFB, RFB on a train and a
                         test layout for the first goal (Figure 8).
Prints the separation statistics: mean distance between episodes of the same layout vs
of different layouts, and nearest-neighbour layout accuracy.
"""

from __future__ import annotations

import argparse
import json
import os

import jax
import jax.numpy as jnp
import numpy as np

import zsbfm
from zsbfm.agents import make_agent
from zsbfm.data import collect
from zsbfm.envs import index_contexts
from zsbfm.envs.render import draw_grid
from zsbfm.plots import value_map


def episode_embeddings(run, split, n_layouts=5, episodes=20, seed=0, key=0):
    """mu of fresh reward-free episodes: (h [n_layouts * episodes, h_dim], layout ids)."""
    cfg = run.cfg
    env = zsbfm.make_env(cfg.env, n_train=cfg.n_train_layouts)
    agent = make_agent(cfg, env)
    params = run.seed_params(seed)
    ctxs = index_contexts(env.contexts(split), jnp.arange(n_layouts))
    env_ctx = zsbfm.make_env(cfg.env, n_train=cfg.n_train_layouts, episode_len=cfg.context_len)
    ds = collect(env_ctx, jax.random.PRNGKey(key), ctxs, episodes)
    mu, _ = agent.encode(params.enc, ds.obs[:, :-1], ds.action, ds.obs[:, 1:])
    return np.asarray(mu), np.asarray(ds.context_id)


def separation(h, ids):
    """Same-layout vs different-layout mean distance (Euclidean and cosine), and
    leave-one-out nearest-neighbour layout accuracy."""
    out = {}
    hn = h / np.linalg.norm(h, axis=1, keepdims=True)
    for name, D in (("euclid", np.linalg.norm(h[:, None] - h[None], axis=-1)), ("cosine", 1 - hn @ hn.T)):
        same = ids[:, None] == ids[None]
        off = ~np.eye(len(ids), dtype=bool)
        D2 = D + np.eye(len(ids)) * 1e9
        out[name] = {"same": float(D[same & off].mean()), "diff": float(D[~same].mean()),
                     "nn_acc": float(np.mean(ids[D2.argmin(1)] == ids))}
    return out


def plot_pca(runs, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(runs), figsize=(4.2 * len(runs), 3.8), squeeze=False)
    stats = {}
    for ax, (name, run) in zip(axes[0], runs.items()):
        h_tr, id_tr = episode_embeddings(run, "train")
        h_te, id_te = episode_embeddings(run, "test", key=1)
        h = np.concatenate([h_tr, h_te])
        mean = h.mean(0)
        _, _, vt = np.linalg.svd(h - mean, full_matrices=False)
        p_tr, p_te = (h_tr - mean) @ vt[:2].T, (h_te - mean) @ vt[:2].T
        cmap = plt.get_cmap("tab10")
        for i in range(5):
            ax.scatter(*p_tr[id_tr == i].T, s=12, color=cmap(i), marker="o", label=f"train {i}")
            ax.scatter(*p_te[id_te == i].T, s=16, color=cmap(i + 5), marker="x", label=f"test {i}")
        stats[name] = {"train": separation(h_tr, id_tr), "test": separation(h_te, id_te)}
        s = stats[name]
        ax.set_title(f"{name}: PCA of h (o train, x test layouts)\nNN layout acc train "
                     f"{s['train']['euclid']['nn_acc']:.2f}, test {s['test']['euclid']['nn_acc']:.2f}",
                     fontsize=8)
    axes[0, -1].legend(fontsize=6, ncol=2, loc="best")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return stats


def plot_q_maps(runs, path, goal_index=0):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, len(runs), figsize=(3.6 * len(runs), 6.4), squeeze=False)
    for col, (name, run) in enumerate(runs.items()):
        cfg = run.cfg
        env = zsbfm.make_env(cfg.env, n_train=cfg.n_train_layouts)
        agent = make_agent(cfg, env)
        params = run.seed_params(0)
        for row, split in enumerate(("train", "test")):
            ctx = index_contexts(env.contexts(split), 0)
            goal = env.eval_goals(ctx)[goal_index]
            v, a = value_map(agent, env, params, ctx, goal, jax.random.PRNGKey(row))
            draw_grid(axes[row, col], np.asarray(ctx.walls), values=np.asarray(v), actions=np.asarray(a),
                      start=(1, 1), goals=[tuple(np.asarray(goal).astype(int))], title=f"{name} {split}")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--env", default="fourrooms")
    p.add_argument("--runs-dir", default="runs")
    p.add_argument("--out", default="results/figures")
    for algo in ("fb", "bfb", "rfb"):
        p.add_argument(f"--{algo}", default=None, help=f"path of the {algo} run")
    a = p.parse_args()
    os.makedirs(a.out, exist_ok=True)
    runs = {}
    for algo in ("fb", "bfb", "rfb"):
        path = getattr(a, algo) or os.path.join(a.runs_dir, f"{a.env}-{algo}-cpu")
        if os.path.exists(os.path.join(path, "config.json")):
            runs[algo.upper()] = zsbfm.load(path)
        else:
            print(f"skipping {algo}: no run at {path}")
    belief = {k: v for k, v in runs.items() if k != "FB"}
    if belief:
        stats = plot_pca(belief, os.path.join(a.out, f"h_pca_{a.env}.png"))
        print(json.dumps(stats, indent=1))
    if runs:
        plot_q_maps(runs, os.path.join(a.out, f"q_maps_{a.env}.png"))
        print(f"wrote figures to {a.out}")


if __name__ == "__main__":
    main()
