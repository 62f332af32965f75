"""How hard the zero-shot AntWind policies push: mean |a|^2 on dataset states, per seed.

    python experiments/antwind_control_cost.py --runs runs/antwind-fb-cpu runs/antwind-bfb-cpu

For each run and seed: z (and h, from one expert context episode in the first train wind)
inferred exactly as in evaluation, then the policy's action on 2,000 reward-sample states
of the dataset. The environment's control cost is 0.5 |a|^2 per step (at most 4 with 8
motors in [-1, 1]), which the inferred reward `state_reward(s')` cannot represent (B
sees states only). Prints mean |a|^2 per seed and the implied control cost per 256-step
episode.
"""

from __future__ import annotations

import argparse

import jax
import jax.numpy as jnp
import numpy as np

from zsbfm.agents import make_agent
from zsbfm.data.expert import load_or_collect_dataset
from zsbfm.data.sources import make_env_for
from zsbfm.envs import index_contexts
from zsbfm.envs.antwind import CTRL_COST
from zsbfm.evaluate import context_episode, reward_states
from zsbfm.run import load


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--runs", nargs="+", default=[f"runs/antwind-{a}-cpu" for a in ("fb", "hilp", "lap", "bfb", "rfb")])
    p.add_argument("--states", type=int, default=2000)
    a = p.parse_args()
    for path in a.runs:
        run = load(path)
        cfg = run.cfg
        env = make_env_for(cfg, progress=False)
        agent = make_agent(cfg, env)
        obs = reward_states(jax.random.PRNGKey(0), load_or_collect_dataset(cfg, env, progress=False))
        context = context_episode(env, jax.random.PRNGKey(1), index_contexts(env.contexts("train"), 0), cfg.context_len)
        sq = []
        for s in range(cfg.num_seeds):
            params = run.seed_params(s)
            task = agent.reward_task(params, obs, env.state_reward(obs), context)
            batch = jax.tree_util.tree_map(lambda x: jnp.broadcast_to(x, (a.states,) + x.shape), task)
            act = agent.act(params, obs[:a.states], batch, jax.random.PRNGKey(2))
            sq.append(float(jnp.mean(jnp.sum(act ** 2, -1))))
        sq = np.asarray(sq)
        print(f"{path}: mean |a|^2 per seed {np.round(sq, 2).tolist()} (max 8) -> control cost per "
              f"{cfg.eval_episode_len}-step episode {np.round(CTRL_COST * sq * cfg.eval_episode_len).astype(int).tolist()}")


if __name__ == "__main__":
    main()
