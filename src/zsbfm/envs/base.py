"""The functional environment contract shared by every zsbfm environment.

An environment is a frozen (hashable, static) description plus pure functions:

    ctxs  = env.contexts("train" | "test")   # stacked context pytree, leading axis = layouts
    ctxs  = env.sample_contexts(key, n)       # fresh random contexts (jittable)
    state = env.reset(key, ctx, goal=None, start=None)
    state = env.step(state, action)           # state.obs, state.reward, state.done

Everything that varies between dynamics (a wall layout, a wind) lives in the context
pytree, never in a static field, so one compiled `step` serves every context under `vmap`.
The state carries its context, so `step` needs nothing else.
"""

from __future__ import annotations

from typing import Any, Protocol

import jax
from flax import struct

Array = jax.Array


@struct.dataclass
class EnvState:
    """One environment's state (a pytree; batch it with vmap).

    obs:      float32[obs_dim], what the agent sees.
    reward:   float32[], reward of the last transition (0 without a goal).
    done:     bool[], goal reached or time limit hit.
    t:        int32[], steps taken in this episode.
    goal:     float32[obs_dim], the task's goal observation (ignored if not has_goal).
    has_goal: bool[], whether a goal-reaching task is set.
    ctx:      the context pytree (dynamics parameters) this episode runs in.
    inner:    env-specific physical state (grid position, velocity, ...).
    """

    obs: Array
    reward: Array
    done: Array
    t: Array
    goal: Array
    has_goal: Array
    ctx: Any
    inner: Any


class Env(Protocol):
    """What the data collection, training and evaluation code relies on."""

    name: str
    obs_dim: int
    episode_len: int
    discrete: bool  # True: actions are int32 in [0, n_actions); False: float32[action_dim]
    n_actions: int  # discrete action count (0 for continuous)
    action_dim: int  # continuous action dimension (0 for discrete)
    obs_low: tuple[float, ...]
    obs_high: tuple[float, ...]

    def contexts(self, split: str) -> Any: ...
    def sample_contexts(self, key: Array, n: int) -> Any: ...
    def reset(self, key: Array, ctx: Any, goal: Array | None = None, start: Array | None = None) -> EnvState: ...
    def step(self, state: EnvState, action: Array) -> EnvState: ...
    def random_action(self, key: Array) -> Array: ...
    def eval_start(self, ctx: Any) -> Array: ...
    def eval_goals(self, ctx: Any) -> Array: ...

    # optional capabilities: every built-in env subclasses EnvBase, which declares their
    # "not supported" defaults, so callers ask the env instead of probing with hasattr
    metric: str
    eval_protocols: tuple[str, ...]
    def behaviour_policy(self, ctx: Any) -> Any: ...
    def behaviour_actions(self, key: Array, length: int) -> Array | None: ...


class EnvBase:
    """The defaults of Env's optional capabilities; an environment subclasses this and
    overrides what it supports.

    metric:            "success" (goal reaching, the default) or "return" (a reward task).
    eval_protocols:    the goal-reaching protocols env.eval_tasks knows, the official first.
    behaviour_policy:  the closed-loop behaviour policy(key, obs) -> action in context ctx,
                       or None (the default: no such policy).
    behaviour_actions: an open-loop behaviour action sequence [length, ...] from key, or
                       None (the default). With neither, the data are uniform random actions.
    """

    metric = "success"
    eval_protocols: tuple[str, ...] = ("paper",)

    def behaviour_policy(self, ctx: Any):
        return None

    def behaviour_actions(self, key: Array, length: int):
        return None


def num_contexts(ctxs: Any) -> int:
    """Length of the leading (layout) axis of a stacked context pytree."""
    return jax.tree_util.tree_leaves(ctxs)[0].shape[0]


def index_contexts(ctxs: Any, idx) -> Any:
    """Select contexts `idx` (an int or an int array) from a stacked context pytree."""
    return jax.tree_util.tree_map(lambda x: x[idx], ctxs)
