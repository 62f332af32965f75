"""Linear algebra written in plain matmuls, for use inside compiled training loops.

Why not `jnp.linalg.solve`: on XLA's CPU backend a solve is a LAPACK custom call (LU, a
100-step pivot loop, two triangular solves); inside the scanned FB update its 100 x 100
solve cost ~6 ms of an ~19 ms update (benchmarks/fb_update_profile.py), where the same
arithmetic as matmuls costs ~1 ms. The FB Q-loss only needs C^-1 z inside a
stop-gradient target, to a relative accuracy far below the TD noise.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def spd_inverse(C: jax.Array, iters: int = 24) -> jax.Array:
    """The inverse of a symmetric positive definite C [d, d] by Newton-Schulz iteration:

        X_0 = I / |C|_F,   X_{k+1} = X_k (2 I - C X_k).

    In C's eigenbasis each eigenvalue l has x_{k+1} = x_k (2 - l x_k), so the error
    e = 1 - l x squares at every step, from e_0 = 1 - l / |C|_F in [0, 1) (|C|_F >= l_max).
    `iters` steps invert every eigenvalue with l >= |C|_F * 2^-(iters - 5) to float32
    precision, i.e. a condition number up to ~2^(iters - 5); smaller eigenvalues get an
    inverse that is too small (never too large or of the wrong sign).
    """
    d = C.shape[-1]
    X = jnp.eye(d, dtype=C.dtype) / jnp.sqrt(jnp.sum(C**2))
    return jax.lax.fori_loop(0, iters, lambda _, X: 2.0 * X - X @ (C @ X), X)
