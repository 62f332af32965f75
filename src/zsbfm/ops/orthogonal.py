"""Orthogonal weight initialisation without LAPACK.

flax's `nn.initializers.orthogonal` orthonormalises a Gaussian matrix with jnp.linalg.qr,
a LAPACK custom call on the CPU. Under `nn.vmap` (the twin F heads) the call is batched,
and jaxlib 0.10's batched QR kernels split their batch over XLA's intra-op thread pool
and wait for it: two of them running at once on a 2-thread pool each hold a thread and
wait for the other's, forever (the size="authors" F hung at init on the 2-core machine).
Here the same matrix is orthonormalised by Gram-Schmidt in plain jnp (a fori_loop over
columns, each projected twice for float32 accuracy): QR with a positive diagonal of R is
exactly Gram-Schmidt, so the result is flax's initialiser's for the same key, up to
rounding (tests/test_authors.py).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp


def gram_schmidt(a: jax.Array) -> jax.Array:
    """Q with orthonormal columns spanning a's columns, a = Q R with diag(R) > 0. a: [n, m], m <= n."""
    n, m = a.shape

    def column(j, q):
        v = a[:, j]
        for _ in range(2):  # classical Gram-Schmidt, twice ("CGS2"): orthogonal to float precision
            v = v - q @ (q.T @ v)
        return q.at[:, j].set(v / jnp.linalg.norm(v))

    return jax.lax.fori_loop(0, m, column, jnp.zeros_like(a))


def orthogonal(scale: float = 1.0):
    """An initialiser with flax's `orthogonal(scale)` semantics (the last axis is the output
    axis; the others are flattened into rows), without a LAPACK call."""

    def init(key, shape, dtype=jnp.float32):
        rows, cols = math.prod(shape[:-1]), shape[-1]
        a = jax.random.normal(key, (max(rows, cols), min(rows, cols)), dtype)
        q = gram_schmidt(a)
        q = q.T if rows < cols else q
        return scale * q.reshape(shape)

    return init
