"""Oracle FB: FB whose F sees the true train-layout index (a diagnostic upper bound).

Training: h = one_hot(layout index of the transition's episode) [n_train_layouts], fed to F
exactly as Belief-FB feeds its inferred h (B stays context-free). Test time: h = one_hot of
the train layout the context's environment equals, and h = 0 for a layout that is not a
train layout (the oracle knows nothing about held-out layouts, so its test column is
reported as a diagnostic of what F does with no context, not as a method's result).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from zsbfm.agents.base import Context
from zsbfm.agents.fb import FBAgent
from zsbfm.data.samplers import Transitions


@dataclasses.dataclass(frozen=True)
class OracleFBAgent(FBAgent):

    @property
    def h_dim(self) -> int:
        return self.cfg.n_train_layouts

    def train_context(self, state, dataset, batch: Transitions, key) -> jax.Array:
        return jax.nn.one_hot(dataset.context_id[batch.episode], self.h_dim)

    def context_h(self, params, context: Context) -> jax.Array:
        if context.layout is None:
            raise ValueError("the oracle needs Context.layout (the environment context) at test time")
        train = self.env.contexts("train")
        same = [jnp.all((t == c).reshape(t.shape[0], -1), axis=-1)
                for t, c in zip(jax.tree_util.tree_leaves(train), jax.tree_util.tree_leaves(context.layout))]
        return jnp.all(jnp.stack(same), axis=0).astype(jnp.float32)
