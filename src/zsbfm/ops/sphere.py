"""Projections onto the sphere of radius sqrt(d) and uniform sampling on it."""

from __future__ import annotations

import jax
import jax.numpy as jnp


def project_to_sphere(x: jax.Array, eps: float = 1e-8) -> jax.Array:
    """x * sqrt(d) / (|x| + eps) along the last axis (d = x.shape[-1]).

    |x| is taken with a gradient that stays finite at x = 0 (d|x|/dx = x / |x| is 0/0
    there): a zero input to a bias-free-at-init B, such as the corner cell (0, 0) under
    raw coordinates, gave a NaN gradient even at zero loss weight. Where x != 0 the value
    and gradient are those of the plain norm."""
    d = x.shape[-1]
    sq = jnp.sum(x * x, axis=-1, keepdims=True)
    nonzero = sq > 0
    norm = jnp.where(nonzero, jnp.sqrt(jnp.where(nonzero, sq, 1.0)), 0.0)
    return jnp.sqrt(d) * x / (norm + eps)


def sample_sphere(key: jax.Array, n: int, d: int) -> jax.Array:
    """n points uniform on the sphere of radius sqrt(d): float32[n, d]."""
    return project_to_sphere(jax.random.normal(key, (n, d)))
