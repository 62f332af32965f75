"""Plain MLP building blocks (flax.linen)."""

from __future__ import annotations

from typing import Sequence

import flax.linen as nn
import jax.numpy as jnp


class FiLM(nn.Module):
    """u <- (1 + gamma(c)) * u + beta(c) with [gamma; beta] = W c + b, zero-initialised.

    u: [..., width]; c: [..., c_dim] (same leading axes). Identity at initialisation.
    """

    @nn.compact
    def __call__(self, u, c):
        gb = nn.Dense(2 * u.shape[-1], kernel_init=nn.initializers.zeros,
                      bias_init=nn.initializers.zeros)(c)
        gamma, beta = jnp.split(gb, 2, axis=-1)
        return (1.0 + gamma) * u + beta


class MLP(nn.Module):
    """Dense layers with ReLU; the first layer is Linear -> LayerNorm -> tanh (`norm_first`).

    The LayerNorm/tanh input layer standardises raw inputs (coordinates, task vectors),
    as in the FB reference architecture. `out=None` returns the last hidden layer;
    `out_relu` puts a ReLU on the output layer too (the reference FB preprocessors).

    x: [..., in] -> [..., out]. With a condition c: [..., c_dim], every hidden
    pre-activation (after the LayerNorm of a norm_first layer, before its nonlinearity) is
    FiLM-modulated by c (`FiLM`, submodules film_<i>); at initialisation the output equals
    the unconditioned MLP's with the same Dense/LayerNorm parameters.
    """

    hidden: Sequence[int]
    out: int | None = None
    norm_first: bool = True
    out_relu: bool = False

    @nn.compact
    def __call__(self, x, c=None):
        for i, h in enumerate(self.hidden):
            x = nn.Dense(h)(x)
            first = i == 0 and self.norm_first
            if first:
                x = nn.LayerNorm()(x)
            if c is not None:
                x = FiLM(name=f"film_{i}")(x, c)
            x = jnp.tanh(x) if first else nn.relu(x)
        if self.out is not None:
            x = nn.Dense(self.out)(x)
            if self.out_relu:
                x = nn.relu(x)
        return x
