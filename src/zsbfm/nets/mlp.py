"""Plain MLP building blocks (flax.linen)."""

from __future__ import annotations

from typing import Sequence

import flax.linen as nn
import jax.numpy as jnp


class MLP(nn.Module):
    """Dense layers with ReLU; the first layer is Linear -> LayerNorm -> tanh.

    The LayerNorm/tanh input layer standardises raw inputs (coordinates, task vectors),
    as in the FB reference architecture. `out=None` returns the last hidden layer.
    """

    hidden: Sequence[int]
    out: int | None = None

    @nn.compact
    def __call__(self, x):
        for i, h in enumerate(self.hidden):
            x = nn.Dense(h)(x)
            x = jnp.tanh(nn.LayerNorm()(x)) if i == 0 else nn.relu(x)
        if self.out is not None:
            x = nn.Dense(self.out)(x)
        return x
