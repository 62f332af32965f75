"""The Random baseline: uniformly random actions, nothing learned.

It goes through the same training and evaluation path as every agent (its update is a
no-op), so its row in a results table is measured exactly like the others.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
from flax import struct

from zsbfm.agents.base import Context, Task
from zsbfm.config import Config
from zsbfm.envs.base import Env


@struct.dataclass
class RandomState:
    step: jax.Array


@dataclasses.dataclass(frozen=True)
class RandomAgent:
    cfg: Config
    env: Env

    def init(self, key) -> RandomState:
        return RandomState(step=jnp.zeros((), jnp.int32))

    def update(self, state, dataset, key, step=None):
        return state.replace(step=state.step + 1), {}

    def run_steps(self, state, dataset, keys, first_step):
        return state.replace(step=state.step + keys.shape[0]), {}

    def eval_params(self, state) -> dict:
        return {"step": state.step}  # nothing learned; a leaf so a Run can be saved

    def _task(self) -> Task:
        return Task(z=jnp.zeros((0,)), h=jnp.zeros((0,)))

    def goal_task(self, params, goal_obs, context: Context) -> Task:
        return self._task()

    def reward_task(self, params, obs, reward, context: Context) -> Task:
        return self._task()

    def act(self, params, obs, task: Task, key):
        return self.env.random_action(key)
