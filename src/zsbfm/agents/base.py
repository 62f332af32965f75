"""The agent protocol every algorithm implements.

An agent is a frozen (hashable) dataclass of static settings with pure methods; all
mutable state is the `state` pytree it returns, so the training loop can scan, vmap over
seeds and checkpoint it without knowing the algorithm:

    state            = agent.init(key)
    state, metrics   = agent.update(state, dataset, key, step)   # samples its own batch
    task             = agent.goal_task(params, goal_obs, context)
    task             = agent.reward_task(params, obs, reward, context)
    action           = agent.act(params, obs, task, key)

`context` is one reward-free episode (obs [T+1, obs_dim], action [T, ...]) of the
behaviour policy in the layout the task lives in; `step` is the global update index,
the same for every seed (unbatched under vmap), for agents with training phases; context-free agents ignore it, belief
agents infer h from it. `params = agent.eval_params(state)` is what acting needs.

An agent with training phases (agents/belief.py) returns every phase's metrics from each
chunk, with placeholders for the phases not running, and names the real ones with
`phase_metrics(first_step, names)`; `chunk_metrics` asks it (or keeps every name).
"""

from __future__ import annotations

from typing import Any, Protocol

import jax
from flax import struct


@struct.dataclass
class Task:
    """What a policy is conditioned on: z (task direction) and h (dynamics context).

    z: float32[..., d]; h: float32[..., h_dim] (h_dim = 0 for context-free agents).
    goal: None, or the embedded goal for agents that re-infer z from the current state at
          every step (HILP: z = normalize(phi(goal) - phi(s))).
    """

    z: jax.Array
    h: jax.Array
    goal: Any = None


@struct.dataclass
class Context:
    """The reward-free episode(s) used to infer the dynamics context: one episode, or with
    Config.context_episodes = K > 1, K episodes of one layout stacked on a leading axis
    (no transition spans two of them)."""

    obs: jax.Array     # [T+1, obs_dim] or [K, T+1, obs_dim]
    action: jax.Array  # [T] or [T, action_dim] (with a leading K axis as obs)
    layout: Any = None  # the environment context itself; only the oracle agent may read it


class Agent(Protocol):
    def init(self, key: jax.Array) -> Any: ...
    def update(self, state: Any, dataset: Any, key: jax.Array, step: jax.Array) -> tuple[Any, dict]: ...
    def eval_params(self, state: Any) -> Any: ...
    def goal_task(self, params: Any, goal_obs: jax.Array, context: Context) -> Task: ...
    def reward_task(self, params: Any, obs: jax.Array, reward: jax.Array, context: Context) -> Task: ...
    def act(self, params: Any, obs: jax.Array, task: Task, key: jax.Array) -> jax.Array: ...


def chunk_metrics(agent, first_step: int, names) -> tuple[str, ...]:
    """The metrics of `names` that a chunk of `agent` starting at update `first_step`
    computed: the agent's `phase_metrics` when it has training phases, else all of them."""
    phase_metrics = getattr(agent, "phase_metrics", None)
    return tuple(names) if phase_metrics is None else phase_metrics(first_step, names)
