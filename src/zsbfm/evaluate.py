"""Zero-shot evaluation: jitted, vmapped greedy rollouts over contexts x tasks (x seeds).

For every context, one reward-free episode of the behaviour policy is collected first
(the test-time context for belief agents; context-free agents ignore it). Then, by the
environment's `metric`:
    "success" (gridworlds, pointmass): for every goal, the agent infers z from the goal and
        that episode and acts greedily from the evaluation start; score 1 if the goal is
        reached within the episode.
    "return" (antwind): the agent infers z from reward-labelled states of the dataset
        (z = reward_task(states, env.state_reward(states))) and that episode; the score
        is the return of one episode from a reset (one "task" per context).
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


def return_rollout(agent, env, params, key, ctx, context: Context, reward_obs, length: int):
    """The environment's return (control cost included) of one greedy episode, with z
    inferred from env.state_reward on the states reward_obs [n, obs_dim] and h from `context`."""
    task = agent.reward_task(params, reward_obs, env.state_reward(reward_obs), context)
    policy = lambda k, obs: agent.act(params, obs, task, k)
    _, _, reward = rollout(env, key, ctx, policy, length)
    return jnp.sum(reward)


def metric_of(env) -> str:
    """"success" (goal reaching) or "return" (a reward task), by environment."""
    return getattr(env, "metric", "success")


def evaluate_params(agent, env, params, key, contexts, goals, length: int, context_len: int,
                    reward_obs=None):
    """Scores of one parameter set (jittable): success bool[n_contexts, n_goals], or for
    metric "return" the returns float32[n_contexts, 1].

    contexts: stacked context pytree [n_contexts, ...]; goals: float32[n_contexts, n_goals,
    obs_dim] (success) or None; reward_obs: float32[n, obs_dim] dataset states for reward
    inference (return).
    """
    n = num_contexts(contexts)
    if metric_of(env) == "return":
        if reward_obs is None:
            raise ValueError(f"env {env.name!r} scores returns: evaluate_params needs reward_obs")

        def one_return(k, ctx):
            k_ctx, k_roll = jax.random.split(k)
            context = context_episode(env, k_ctx, ctx, context_len)
            return return_rollout(agent, env, params, k_roll, ctx, context, reward_obs, length)[None]

        return jax.vmap(one_return)(jax.random.split(key, n), contexts)
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
    """env.eval_goals of every context: float32[n_contexts, n_goals, obs_dim] (None for
    environments scored by return)."""
    if metric_of(env) == "return":
        return None
    return jax.vmap(env.eval_goals)(contexts)


REWARD_SAMPLES = 10_000  # dataset states z is inferred from (metric "return")


def reward_states(key, dataset, n: int = REWARD_SAMPLES):
    """n states drawn uniformly from the dataset, for reward inference."""
    from zsbfm.data.samplers import sample_states

    return sample_states(key, dataset, n)


def split_results(success) -> dict:
    """Summaries of scores [seeds, n_contexts, n_goals] as plain lists (the "success" key
    holds the mean score per seed: a success rate, or a return for metric "return")."""
    s = jnp.asarray(success, jnp.float32)
    return {"success": s.mean((1, 2)).tolist(), "per_layout": s.mean(2).tolist(),
            "per_goal": s.mean(1).tolist()}


def evaluate(run, contexts=None, goals=None, key=None, split: str = "test"):
    """Evaluate every seed of a trained `Run` zero-shot.

    contexts: stacked contexts (default: env.contexts(split)); goals: float32[n_contexts,
    n_goals, obs_dim] (default: the environment's evaluation goals). Returns success
    bool[seeds, n_contexts, n_goals], or returns float32[seeds, n_contexts, 1] for antwind.
    """
    from zsbfm.agents import make_agent
    from zsbfm.envs import make_env_for

    cfg = run.cfg
    env = make_env_for(cfg)
    agent = make_agent(cfg, env)
    contexts = env.contexts(split) if contexts is None else contexts
    key = jax.random.PRNGKey(cfg.seed + 1) if key is None else key
    reward_obs = None
    if metric_of(env) == "return":  # z from the run's (cached) dataset; goals unused
        from zsbfm.data.expert import load_or_collect_dataset

        key, k_states = jax.random.split(key)
        reward_obs = reward_states(k_states, load_or_collect_dataset(cfg, env))
    else:
        goals = default_goals(env, contexts) if goals is None else jnp.asarray(goals, jnp.float32)
        if goals.ndim != 3 or goals.shape[-1] != env.obs_dim:
            raise ValueError(f"goals must be [n_contexts, n_goals, {env.obs_dim}], got shape {goals.shape}")
    seeds = jax.tree_util.tree_leaves(run.params)[0].shape[0]
    fn = jax.jit(jax.vmap(lambda p, k: evaluate_params(agent, env, p, k, contexts, goals,
                                                       cfg.eval_episode_len, cfg.context_len, reward_obs)))
    return fn(run.params, jax.random.split(key, seeds))
