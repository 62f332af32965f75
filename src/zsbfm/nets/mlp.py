"""Plain MLP building blocks (flax.linen)."""

from __future__ import annotations

import functools
from typing import Sequence

import flax.linen as nn
import jax.numpy as jnp

from zsbfm.ops.matmul import matmul
from zsbfm.ops.orthogonal import orthogonal


def _dense_dot_general(lhs, rhs, dimension_numbers, precision=None, preferred_element_type=None):
    """nn.Dense's contraction (lhs's last axis with the kernel's first) through `matmul`."""
    del precision, preferred_element_type  # nn.Dense passes its defaults (None)
    if dimension_numbers != (((lhs.ndim - 1,), (0,)), ((), ())):
        raise ValueError(f"Dense contraction expected, got dimension_numbers={dimension_numbers}")
    return matmul(lhs, rhs)


# flax's Dense (same parameters, names and initialisers) with ops.matmul's backward products
Dense = functools.partial(nn.Dense, dot_general=_dense_dot_general)


class MLP(nn.Module):
    """Dense layers with ReLU; the first layer is Linear -> LayerNorm -> tanh (`norm_first`).

    The LayerNorm/tanh input layer standardises raw inputs (coordinates, task vectors),
    as in the FB reference architecture. `out=None` returns the last hidden layer;
    `out_relu` puts a ReLU on the output layer too (the reference FB preprocessors).

    x: [..., in] -> [..., out].
    """

    hidden: Sequence[int]
    out: int | None = None
    norm_first: bool = True
    out_relu: bool = False

    @nn.compact
    def __call__(self, x):
        for i, h in enumerate(self.hidden):
            x = Dense(h)(x)
            first = i == 0 and self.norm_first
            if first:
                x = nn.LayerNorm()(x)
            x = jnp.tanh(x) if first else nn.relu(x)
        if self.out is not None:
            x = Dense(self.out)(x)
            if self.out_relu:
                x = nn.relu(x)
        return x


class NormedMLP(nn.Module):
    """The MLP of the authors' code (F and B of BeliefConditionedFB, `utils/networks.py`):
    the first hidden layer Dense -> tanh -> LayerNorm, every later hidden layer
    Dense -> GELU -> LayerNorm, a linear output; orthogonal initialisation throughout
    (ops.orthogonal: flax's initialiser without its LAPACK call).

    x: [..., in] -> [..., out].
    """

    hidden: Sequence[int]
    out: int

    @nn.compact
    def __call__(self, x):
        init = orthogonal()
        for i, h in enumerate(self.hidden):
            x = Dense(h, kernel_init=init)(x)
            x = nn.LayerNorm()(jnp.tanh(x) if i == 0 else nn.gelu(x))
        return Dense(self.out, kernel_init=init)(x)
