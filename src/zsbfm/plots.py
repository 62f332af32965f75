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


# Notes drawn under a metric's panel title: what a reader would otherwise ask about.
METRIC_NOTES = {
    "fb_loss": "rises as M grows: -mean diag F^T B\n(the diagonal term) dominates",
    "fb_diag": "-mean_i F(s_i,a_i)^T B(s'_i)",
    "M_head_gap": "E|Mbar_1 - Mbar_2| = g; min target: M_offdiag\n-> (1 - gamma g / 2) / (1 - gamma)",
}
NOT_METRICS = ("chunk", "step", "seconds", "wall_s", "flops", "dropped")


def dropped_seeds(run) -> dict:
    """{seed: chunk} of the seeds a run dropped for going non-finite (Config.on_nonfinite)."""
    return {d["seed"]: d["chunk"] for d in run.results.get("dropped", [])}


def plot_metrics(run, path):
    """One panel per logged training metric against gradient steps, one line per seed (each
    metric over the chunks that computed it: a belief run's phases log different ones); a
    dropped seed's line is dashed and ends where it went non-finite."""
    plt = _plt()
    rows = run.metrics
    keys = list(dict.fromkeys(k for r in rows for k in r if k not in NOT_METRICS and not k.startswith("eval/")))
    if not keys:
        return None
    dropped = dropped_seeds(run)
    cols = min(4, len(keys))
    nrows = -(-len(keys) // cols)
    fig, axes = plt.subplots(nrows, cols, figsize=(3.6 * cols, 2.8 * nrows), squeeze=False)
    for ax, k in zip(axes.flat, keys):
        logged = [r for r in rows if k in r]
        steps = [r["step"] for r in logged]
        values = np.asarray([r[k] for r in logged], float).reshape(len(logged), -1)  # None -> NaN
        for i in range(values.shape[1]):
            label = f"seed {i}" + (f" (dropped, chunk {dropped[i]})" if i in dropped else "")
            ax.plot(steps, values[:, i], label=label, linestyle="--" if i in dropped else "-")
        ax.set_title(k + ("\n" + METRIC_NOTES[k] if k in METRIC_NOTES else ""), fontsize=8)
        ax.set_xlabel("update", fontsize=8)
    axes.flat[0].legend(fontsize=7)
    for ax in axes.flat[len(keys):]:
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def curve_arrays(metrics: list[dict]) -> tuple[np.ndarray, np.ndarray, dict]:
    """The learning curve of a metrics log: (updates [T], FLOPs [T], {"<split>/<protocol>":
    scores [T, seeds]}) over the rows that hold an evaluation."""
    rows = [m for m in metrics if any(k.startswith("eval/") for k in m)]
    keys = sorted({k for m in rows for k in m if k.startswith("eval/")})
    steps = np.asarray([m["step"] for m in rows], float)
    flops = np.asarray([m.get("flops", np.nan) for m in rows], float)
    return steps, flops, {k[5:]: np.asarray([m[k] for m in rows], float).reshape(len(rows), -1) for k in keys}


def plot_curves(lines: dict, path, title: str = ""):
    """Success against updates and against FLOPs, one line (mean over seeds, band = min..max)
    per entry of `lines` ({label: metrics list}), one row of panels per split/protocol."""
    plt = _plt()
    data = {label: curve_arrays(m) for label, m in lines.items()}
    order = {"paper": 0, "dense": 1, "random_start": 2, "return": 3}
    keys = sorted({k for _, _, c in data.values() for k in c},
                  key=lambda k: (order.get(k.split("/")[1], 9), k.split("/")[0] != "train"))
    if not keys:
        return None
    fig, axes = plt.subplots(len(keys), 2, figsize=(9, 2.6 * len(keys)), squeeze=False)
    for row, k in zip(axes, keys):
        for label, (steps, flops, c) in data.items():
            if k not in c:
                continue
            if not np.isfinite(c[k]).any(1).all():  # every seed of a point dropped
                continue
            mean, lo, hi = np.nanmean(c[k], 1), np.nanmin(c[k], 1), np.nanmax(c[k], 1)  # dropped seeds: None
            for ax, x in ((row[0], steps), (row[1], flops)):
                (line,) = ax.plot(x, mean, marker=".", label=label)
                ax.fill_between(x, lo, hi, color=line.get_color(), alpha=0.15)
        row[0].set_ylabel(k.replace("/", "\n"), fontsize=8)
        row[0].set_xlabel("updates", fontsize=8)
        row[1].set_xlabel("FLOPs (XLA cost analysis x updates)", fontsize=8)
        row[1].set_xscale("log")
        from matplotlib.ticker import NullFormatter

        row[1].xaxis.set_minor_formatter(NullFormatter())
        for ax in row:
            ax.set_ylim(0, 1) if "return" not in k else None
            ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=7)
    if title:
        fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def plot_sweep(result, root):
    """sweep.png: per point, the official and dense scores (mean +- std over seeds) on train
    and test; curves.png: every point's learning curve (when logged)."""
    plt = _plt()
    points = result.points
    protos = [p for p in ("paper", "dense", "return") if any(p in pt["protocols"] for pt in points)]
    fig, axes = plt.subplots(1, len(protos), figsize=(max(5, 0.9 * len(points) + 2) * len(protos) / 1.5, 3.4),
                             squeeze=False)
    x = np.arange(len(points))
    for ax, p in zip(axes[0], protos):
        for j, (split, color) in enumerate((("train", "tab:blue"), ("test", "tab:orange"))):
            v = [np.asarray(pt["protocols"].get(p, {}).get(split, [np.nan]), float) for pt in points]
            v = [a[np.isfinite(a)] for a in v]  # a dropped seed's score is None
            ax.bar(x + (j - 0.5) * 0.4, [a.mean() if a.size else 0.0 for a in v], 0.4,
                   yerr=[a.std() if a.size else 0.0 for a in v], color=color, capsize=3, label=split)
        ax.set_xticks(x, [pt["label"] + (f"\n(seeds {pt['dropped']} dropped)" if pt.get("dropped") else "")
                          for pt in points], rotation=60, ha="right", fontsize=7)
        ax.set_title(f"{p} protocol", fontsize=9)
        ax.set_ylabel("episode return" if p == "return" else "success rate")
    axes[0, 0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(os.path.join(root, "sweep.png"), dpi=100)
    plt.close(fig)
    if any(pt["curve"] for pt in points):
        plot_curves({pt["label"]: pt["curve"] for pt in points}, os.path.join(root, "curves.png"),
                    title=f"sweep {result.cfg.run_name} ({result.cfg.env}, {result.cfg.algo})")


def plot_success(run, path):
    """Mean +- std over seeds of the success rate (or return) on train and test contexts."""
    plt = _plt()
    splits = ("train", "test")
    dropped = dropped_seeds(run)
    vals = [np.asarray([v for v in run.results[s] if v is not None], float) for s in splits]
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
    ax.set_title(f"{run.cfg.env} {run.cfg.algo} ({len(vals[0])} seeds"
                 + (f"; seeds {sorted(dropped)} dropped: non-finite" if dropped else "") + ")", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def value_map(agent, env, params, ctx, goal, key):
    """V(s) = max_a Q(s, a) and the greedy action on every cell, for z from `goal`
    (traceable: plot_value_maps jits it once for both panels).

    Returns (values float[H, W], actions int[H, W]) for one parameter set.
    """
    from zsbfm.evaluate import context_episode

    size = env.size
    ys, xs = jnp.mgrid[0:size, 0:size]
    cells = jnp.stack([xs.reshape(-1), ys.reshape(-1)], -1).astype(jnp.float32)
    context = context_episode(env, key, ctx, agent.cfg.context_len, agent.cfg.context_episodes)
    task = agent.goal_task(params, goal, context)
    q = agent.q_values(params, cells, jax.tree_util.tree_map(
        lambda x: jnp.broadcast_to(x, (cells.shape[0],) + x.shape), task))
    return q.max(-1).reshape(size, size), q.argmax(-1).reshape(size, size)


def plot_value_maps(run, path, seed: int = 0, goal_index: int = 0):
    """Value maps and greedy arrows of one seed on the first train and test layout."""
    from zsbfm.agents import make_agent
    from zsbfm.envs import env_spec, index_contexts, make_env
    from zsbfm.envs.render import render_layouts

    cfg = run.cfg
    env = make_env(cfg.env, n_train=cfg.n_train_layouts, episode_len=cfg.episode_len)
    agent = make_agent(cfg, env)
    if not (env_spec(cfg.env).finite_states and env.discrete) or not hasattr(agent, "q_values"):
        return None  # value maps are drawn on grids (every cell a state), for agents with Q-values
    params = run.seed_params(seed)
    # one compiled program for both panels (eagerly, every op would compile on its own)
    value_map_fn = jax.jit(lambda params, ctx, goal, key: value_map(agent, env, params, ctx, goal, key))
    panels = []
    for split in ("train", "test"):
        ctx = index_contexts(env.contexts(split), 0)
        goal = env.eval_goals(ctx)[goal_index]
        v, a = value_map_fn(params, ctx, goal, jax.random.PRNGKey(0))
        panels.append(dict(walls=np.asarray(ctx.walls), values=np.asarray(v), actions=np.asarray(a),
                           start=tuple(np.asarray(env.eval_start(ctx)).astype(int)),
                           goals=[tuple(np.asarray(goal).astype(int))],
                           title=f"{cfg.algo} {split} layout 0, seed {seed}"))
    return render_layouts(path, panels)


def plot_run(run, run_dir):
    """Write every plot of a run into its directory."""
    plot_metrics(run, os.path.join(run_dir, "metrics.png"))
    plot_curves({run.cfg.run_name: run.metrics}, os.path.join(run_dir, "curves.png"))
    plot_success(run, os.path.join(run_dir, "success.png"))
    kept = [i for i in range(len(run.results["train"])) if i not in dropped_seeds(run)]
    if kept:
        plot_value_maps(run, os.path.join(run_dir, "value_maps.png"), seed=kept[0])
