"""Zero-shot evaluation: jitted, vmapped greedy rollouts over contexts x goals (x seeds).

For every context, one reward-free episode of the behaviour policy is collected first
(the test-time context for belief agents; context-free agents ignore it). For every goal,
the agent infers its task from the goal and that episode, then acts greedily from the
environment's evaluation start. Success = the goal was reached within the episode.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from zsbfm.agents.base import Context
from zsbfm.data.collect import behaviour_rollout, rollout
from zsbfm.envs.base import index_contexts, num_contexts


def context_episode(env, key, ctx, length: int) -> Context:
    """One reward-free behaviour-policy episode of `length` steps in `ctx` (and `ctx` itself,
    which only the oracle diagnostic reads)."""
    obs, action, _ = behaviour_rollout(env, key, ctx, length)
    return Context(obs=obs, action=action, layout=ctx)


def goal_rollout(agent, env, params, key, ctx, context: Context, goal, length: int):
    """Greedy episode towards `goal` from env.eval_start(ctx). Returns (success, obs [T+1, d])."""
    task = agent.goal_task(params, goal, context)
    policy = lambda k, obs: agent.act(params, obs, task, k)
    obs, _, reward = rollout(env, key, ctx, policy, length, goal=goal, start=env.eval_start(ctx))
    return jnp.any(reward > 0), obs


def evaluate_params(agent, env, params, key, contexts, goals, length: int, context_len: int):
    """Success bool[n_contexts, n_goals] of one parameter set (jittable).

    contexts: stacked context pytree [n_contexts, ...]; goals: float32[n_contexts, n_goals, obs_dim].
    """
    n = num_contexts(contexts)
    if goals.shape[0] != n:
        raise ValueError(f"goals must have shape [n_contexts={n}, n_goals, obs_dim], got {goals.shape}")

    def one_context(k, ctx, ctx_goals):
        k_ctx, k_roll = jax.random.split(k)
        context = context_episode(env, k_ctx, ctx, context_len)
        keys = jax.random.split(k_roll, ctx_goals.shape[0])
        success, _ = jax.vmap(lambda kk, g: goal_rollout(agent, env, params, kk, ctx, context, g, length))(
            keys, ctx_goals)
        return success

    return jax.vmap(one_context)(jax.random.split(key, n), contexts, goals)


def default_goals(env, contexts):
    """env.eval_goals of every context: float32[n_contexts, n_goals, obs_dim]."""
    return jax.vmap(env.eval_goals)(contexts)


def split_results(success) -> dict:
    """Summaries of success [seeds, n_contexts, n_goals] as plain lists."""
    s = jnp.asarray(success, jnp.float32)
    return {"success": s.mean((1, 2)).tolist(), "per_layout": s.mean(2).tolist(),
            "per_goal": s.mean(1).tolist()}


def evaluate(run, contexts=None, goals=None, key=None, split: str = "test"):
    """Evaluate every seed of a trained `Run` zero-shot.

    contexts: stacked contexts (default: env.contexts(split)); goals: float32[n_contexts,
    n_goals, obs_dim] (default: the environment's evaluation goals). Returns success
    bool[seeds, n_contexts, n_goals].
    """
    from zsbfm.agents import make_agent
    from zsbfm.envs import make_env

    cfg = run.cfg
    env = make_env(cfg.env, n_train=cfg.n_train_layouts, episode_len=cfg.episode_len)
    agent = make_agent(cfg, env)
    contexts = env.contexts(split) if contexts is None else contexts
    goals = default_goals(env, contexts) if goals is None else jnp.asarray(goals, jnp.float32)
    if goals.ndim != 3 or goals.shape[-1] != env.obs_dim:
        raise ValueError(f"goals must be [n_contexts, n_goals, {env.obs_dim}], got shape {goals.shape}")
    key = jax.random.PRNGKey(cfg.seed + 1) if key is None else key
    seeds = jax.tree_util.tree_leaves(run.params)[0].shape[0]
    fn = jax.jit(jax.vmap(lambda p, k: evaluate_params(agent, env, p, k, contexts, goals,
                                                       cfg.eval_episode_len, cfg.context_len)))
    return fn(run.params, jax.random.split(key, seeds))
