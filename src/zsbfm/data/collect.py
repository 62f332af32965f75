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

    policy(key, obs) -> action. Returns (obs float32[length+1, obs_dim],
    action [length, ...], reward float32[length]).
    """
    k_reset, k_steps = jax.random.split(key)
    state = env.reset(k_reset, ctx, goal=goal, start=start)

    def step(state, k):
        action = policy(k, state.obs)
        nxt = env.step(state, action)
        return nxt, (nxt.obs, action, nxt.reward)

    _, (obs, action, reward) = jax.lax.scan(step, state, jax.random.split(k_steps, length))
    return jnp.concatenate([state.obs[None], obs]), action, reward


def collect(env: Env, key: jax.Array, contexts, episodes_per_context: int, policy=None) -> Dataset:
    """Collect `episodes_per_context` reward-free episodes in every context (jittable).

    Episodes are context-major: episode e runs in context e // episodes_per_context.
    Each episode gets its own key; starts are uniformly random free states (env.reset).
    """
    policy = policy or uniform_policy(env)
    n_ctx = num_contexts(contexts)
    ctx_id = jnp.repeat(jnp.arange(n_ctx, dtype=jnp.int32), episodes_per_context)
    keys = jax.random.split(key, n_ctx * episodes_per_context)

    def one(k, cid):
        obs, action, _ = rollout(env, k, index_contexts(contexts, cid), policy, env.episode_len)
        return obs, action

    obs, action = jax.vmap(one)(keys, ctx_id)
    return Dataset(obs=obs, action=action, context_id=ctx_id)
