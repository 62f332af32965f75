"""Oracle FB: FB whose F sees the true context (a diagnostic upper bound).

Config.oracle_context chooses what the oracle is told:
  "id":    h = one_hot(layout index of the transition's episode) [n_train_layouts]. Test
           time: the one-hot of the train layout the context's environment equals, and
           h = 0 for a layout that is not a train layout (the oracle knows nothing about
           held-out layouts, so its test column is a diagnostic of what F does with no
           context, not a method's result).
  "walls": h = env.context_features(layout), the layout's own description (gridworlds: the
           interior wall map), on train and held-out layouts alike: what a perfect context
           encoder could give F, and whether F generalises from it to unseen dynamics.
h is fed to F exactly as Belief-FB feeds its inferred h (B stays context-free).
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
        if self.cfg.oracle_context == "walls":
            return self.env.context_features(jax.tree_util.tree_map(lambda x: x[0], self.env.contexts("train"))).shape[-1]
        return self.cfg.n_train_layouts

    def train_context(self, state, dataset, batch: Transitions, key) -> jax.Array:
        layout = dataset.context_id[batch.episode]
        if self.cfg.oracle_context == "walls":
            feats = jax.vmap(self.env.context_features)(self.env.contexts("train"))   # [n_train, k]
            return feats[layout]
        return jax.nn.one_hot(layout, self.h_dim)

    def context_h(self, params, context: Context) -> jax.Array:
        if context.layout is None:
            raise ValueError("the oracle needs Context.layout (the environment context) at test time")
        if self.cfg.oracle_context == "walls":
            return self.env.context_features(context.layout)
        train = self.env.contexts("train")
        same = [jnp.all((t == c).reshape(t.shape[0], -1), axis=-1)
                for t, c in zip(jax.tree_util.tree_leaves(train), jax.tree_util.tree_leaves(context.layout))]
        return jnp.all(jnp.stack(same), axis=0).astype(jnp.float32)
