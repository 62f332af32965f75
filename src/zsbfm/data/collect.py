"""On-device data collection: one vmapped scan over contexts x episodes."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from zsbfm.data.dataset import Dataset
from zsbfm.envs.base import Env, index_contexts, num_contexts


def uniform_policy(env: Env):
    """Behaviour policy: uniformly random actions. policy(key, obs) -> action."""
    return lambda key, obs: env.random_action(key)


def rollout(env: Env, key: jax.Array, ctx, policy, length: int, goal=None, start=None):
    """One episode of `length` steps in context `ctx` (jittable).

    policy: a function policy(key, obs) -> action, or an array [length, ...] of open-loop
    actions. Returns (obs float32[length+1, obs_dim], action [length, ...], reward float32[length]).
    """
    k_reset, k_steps = jax.random.split(key)
    state = env.reset(k_reset, ctx, goal=goal, start=start)
    open_loop = not callable(policy)
    keys = jax.random.split(k_steps, length)

    def step(state, xs):
        k, a = xs
        action = a if open_loop else policy(k, state.obs)
        nxt = env.step(state, action)
        return nxt, (nxt.obs, action, nxt.reward)

    _, (obs, action, reward) = jax.lax.scan(step, state, (keys, policy if open_loop else keys))
    return jnp.concatenate([state.obs[None], obs]), action, reward


def behaviour_rollout(env: Env, key: jax.Array, ctx, length: int):
    """One reward-free episode of the environment's behaviour policy: its closed-loop
    `behaviour_policy(ctx)` (antwind: the noisy expert), its open-loop `behaviour_actions`
    (pointmass: sticky directions), else uniform actions."""
    policy = env.behaviour_policy(ctx)
    if policy is not None:
        return rollout(env, key, ctx, policy, length)
    k_act, k_roll = jax.random.split(key)
    actions = env.behaviour_actions(k_act, length)
    if actions is not None:
        return rollout(env, k_roll, ctx, actions, length)
    return rollout(env, key, ctx, uniform_policy(env), length)


def behaviour_returns(env: Env, key: jax.Array, contexts, episodes: int) -> jax.Array:
    """Undiscounted returns [n_contexts, episodes] of the behaviour policy (`behaviour_rollout`;
    antwind: the expert, with its noise), one env.episode_len-step episode per (context, key);
    the keys are split from `key` (jittable; the reference returns of
    experiments/antwind_expert*.py)."""
    n = num_contexts(contexts)
    keys = jax.random.split(key, n * episodes).reshape(n, episodes, -1)
    one = lambda k, ctx: behaviour_rollout(env, k, ctx, env.episode_len)[2].sum()
    return jax.vmap(jax.vmap(one, in_axes=(0, None)))(keys, contexts)


def collect(env: Env, key: jax.Array, contexts, episodes_per_context: int, policy=None) -> Dataset:
    """Collect `episodes_per_context` reward-free episodes in every context (jittable).

    Episodes are context-major: episode e runs in context e // episodes_per_context.
    Each episode gets its own key; starts are uniformly random free states (env.reset).
    policy: None for the environment's behaviour policy (`behaviour_rollout`), or
    policy(key, obs) -> action.
    """
    n_ctx = num_contexts(contexts)
    ctx_id = jnp.repeat(jnp.arange(n_ctx, dtype=jnp.int32), episodes_per_context)
    keys = jax.random.split(key, n_ctx * episodes_per_context)

    def one(k, cid):
        ctx = index_contexts(contexts, cid)
        if policy is None:
            obs, action, _ = behaviour_rollout(env, k, ctx, env.episode_len)
        else:
            obs, action, _ = rollout(env, k, ctx, policy, env.episode_len)
        return obs, action

    obs, action = jax.vmap(one)(keys, ctx_id)
    return Dataset(obs=obs, action=action, context_id=ctx_id)
