"""Projections onto the sphere of radius sqrt(d) and uniform sampling on it."""

from __future__ import annotations

import jax
import jax.numpy as jnp


def project_to_sphere(x: jax.Array, eps: float = 1e-8) -> jax.Array:
    """x * sqrt(d) / |x| along the last axis (d = x.shape[-1])."""
    d = x.shape[-1]
    return jnp.sqrt(d) * x / (jnp.linalg.norm(x, axis=-1, keepdims=True) + eps)


def sample_sphere(key: jax.Array, n: int, d: int) -> jax.Array:
    """n points uniform on the sphere of radius sqrt(d): float32[n, d]."""
    return project_to_sphere(jax.random.normal(key, (n, d)))
