"""A matrix product whose backward pass XLA's CPU dots run fast (docs/results.md, "Throughput").

Same value and gradients as the plain product; only the shapes of the backward products
differ. On the 2-core CPU, XLA's dots run a product that contracts a transposed operand
(x^T g, g W^T) at ~100-130 GFLOP/s where the plain [p, q] x [q, r] product reaches ~170.
At large sizes, writing the transposed operand out first and then multiplying plainly is
1.2-1.5x faster, the copy included; at the CPU presets' sizes (256 wide) it is slower, so
the rule is by size (LARGE_DIM, static: shapes are known at trace time).

A `jax.custom_vjp`: reverse mode only (jax.grad, jax.vjp); forward mode (jax.jvp,
jax.jacfwd) through it raises.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import lax

# The smallest sides of the matrix to transpose at which it is written out (measured on the
# 2-core CPU: 512 and 1024 gain, 256 and 122 lose).
LARGE_DIM = 512


def written_transpose(a):
    """a^T over the last two axes, materialised: the optimization barrier keeps XLA from
    folding the transpose back into the product that reads it."""
    return lax.optimization_barrier(jnp.swapaxes(a, -1, -2))


def _large(a) -> bool:
    return min(a.shape[-2:]) >= LARGE_DIM


@jax.custom_vjp
def matmul(x, kernel):
    """y = x @ kernel: x [..., i], kernel [i, o] -> [..., o] (a Dense layer's product).

    Backward: dkernel = x^T g, formed in the kernel's [i, o] layout (JAX's own rule forms
    (g^T x)^T, and under vmap XLA keeps that transpose as a copy fused into the optimizer's
    update); dx = g kernel^T. Transposed operands are written out when large."""
    return x @ kernel


def _matmul_fwd(x, kernel):
    return x @ kernel, (x, kernel)


def _matmul_bwd(res, g):
    x, kernel = res
    x2, g2 = x.reshape(-1, x.shape[-1]), g.reshape(-1, g.shape[-1])  # [n, i], [n, o]
    if _large(x2) and _large(kernel):
        return g @ written_transpose(kernel), written_transpose(x2) @ g2
    dx = lax.dot_general(g, kernel, (((g.ndim - 1,), (1,)), ((), ())))  # g kernel^T: [..., i]
    dk = lax.dot_general(x2, g2, (((0,), (0,)), ((), ())))              # x^T g: [i, o]
    return dx, dk


matmul.defvjp(_matmul_fwd, _matmul_bwd)
