"""Pointmass mazes with behaviour trajectories and, given a trained run, its goal rollouts.

    python experiments/pointmass_figure.py                          # behaviour data only
    python experiments/pointmass_figure.py --run runs/pointmass-fb-cpu

Writes results/figures/pointmass_behaviour.png (5 train and 5 test mazes, 3 behaviour
episodes each) and, with --run, results/figures/pointmass_rollouts_<algo>.png (seed 0's
rollout from the evaluation start to the BFS-farthest goal, green disc = success radius).
"""

from __future__ import annotations

import argparse
import os

import jax
import jax.numpy as jnp
import numpy as np

import zsbfm
from zsbfm.agents import make_agent
from zsbfm.data.collect import behaviour_rollout
from zsbfm.envs import index_contexts
from zsbfm.envs.render import render_mazes
from zsbfm.evaluate import context_episode, goal_rollout


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--run", default="")
    p.add_argument("--out", default="results/figures")
    a = p.parse_args()
    os.makedirs(a.out, exist_ok=True)
    env = zsbfm.make_env("pointmass")
    walls, paths, starts, goals, titles = [], [], [], [], []
    for split in ("train", "test"):
        ctxs = env.contexts(split)
        for i in range(5):
            ctx = index_contexts(ctxs, i)
            keys = jax.random.split(jax.random.PRNGKey(i), 3)
            eps = [np.asarray(behaviour_rollout(env, k, ctx, env.episode_len)[0]) for k in keys]
            walls.append(np.asarray(ctx.walls))
            paths.append(eps)
            starts.append(np.asarray(env.eval_start(ctx)))
            goals.append(np.asarray(env.eval_goals(ctx)[0]))
            titles.append(f"{split} maze {i}")
    out = render_mazes(os.path.join(a.out, "pointmass_behaviour.png"), np.stack(walls), paths,
                       np.stack(starts), np.stack(goals), titles=titles)
    print("wrote", out)
    if not a.run:
        return

    run = zsbfm.load(a.run)
    cfg = run.cfg
    env = zsbfm.make_env("pointmass", n_train=cfg.n_train_layouts, episode_len=cfg.episode_len)
    agent = make_agent(cfg, env)
    params = run.seed_params(0)
    rollouts, titles = [], []
    for split in ("train", "test"):
        ctxs = env.contexts(split)
        for i in range(5):
            ctx = index_contexts(ctxs, i)
            k_ctx, k_roll = jax.random.split(jax.random.PRNGKey(100 + i))
            context = context_episode(env, k_ctx, ctx, cfg.context_len)
            ok, obs = goal_rollout(agent, env, params, k_roll, ctx, context, env.eval_goals(ctx)[0],
                                   cfg.eval_episode_len)
            rollouts.append([np.asarray(obs)])
            titles.append(f"{cfg.algo} {split} {i}: {'success' if ok else 'fail'}")
    out = render_mazes(os.path.join(a.out, f"pointmass_rollouts_{cfg.algo}.png"), np.stack(walls),
                       rollouts, np.stack(starts), np.stack(goals), titles=titles)
    print("wrote", out)


if __name__ == "__main__":
    main()
