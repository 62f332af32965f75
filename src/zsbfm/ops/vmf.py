"""Exact von Mises-Fisher sampling on the unit sphere S^{d-1} (Wood 1994), jittable.

A sample around mean direction mu is built in three steps:
  1. w = mu^T x, the cosine to the mean, drawn by Wood's rejection sampler;
  2. x = (w, sqrt(1 - w^2) v) around the north pole e1, v uniform on S^{d-2};
  3. the Householder reflection H = I - 2 u u^T, u = (e1 - mu) / |e1 - mu|, maps e1 to mu.
Moments used by the tests: E[w] = A_d(kappa) = I_{d/2}(kappa) / I_{d/2-1}(kappa) and
E[w^2] = 1 - (d - 1) A_d(kappa) / kappa.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def sample_vmf_cosine(key: jax.Array, n: int, d: int, kappa: float) -> jax.Array:
    """n draws of w = mu^T x for x ~ vMF(mu, kappa) on S^{d-1}: float32[n].

    Wood's algorithm, rejection step included: every row redraws (Beta, uniform) pairs
    until accepted; the loop runs until all n rows are accepted.
    """
    m1 = d - 1.0
    kappa = jnp.asarray(kappa, jnp.float32)
    # b = (-2k + sqrt(4k^2 + (d-1)^2)) / (d-1), in the cancellation-free form.
    b = m1 / (2.0 * kappa + jnp.sqrt(4.0 * kappa**2 + m1**2))
    x0 = (1.0 - b) / (1.0 + b)
    c = kappa * x0 + m1 * jnp.log(1.0 - x0**2)

    def propose(k):
        k_beta, k_u = jax.random.split(k)
        z = jax.random.beta(k_beta, m1 / 2.0, m1 / 2.0, (n,))
        w = (1.0 - (1.0 + b) * z) / (1.0 - (1.0 - b) * z)
        u = jax.random.uniform(k_u, (n,), minval=jnp.finfo(jnp.float32).tiny)
        accept = kappa * w + m1 * jnp.log(1.0 - x0 * w) - c >= jnp.log(u)
        return w, accept

    def cond(carry):
        return ~jnp.all(carry[1])

    def body(carry):
        w, done, k = carry
        k, sub = jax.random.split(k)
        w_new, acc = propose(sub)
        take = ~done & acc
        return jnp.where(take, w_new, w), done | acc, k

    k0, k_loop = jax.random.split(key)
    w, acc = propose(k0)
    w, _, _ = jax.lax.while_loop(cond, body, (w, acc, k_loop))
    return w


def sample_vmf_north(key: jax.Array, n: int, d: int, kappa: float) -> jax.Array:
    """n unit vectors ~ vMF(e1, kappa) in R^d: float32[n, d]."""
    k_w, k_v = jax.random.split(key)
    w = sample_vmf_cosine(k_w, n, d, kappa)
    v = jax.random.normal(k_v, (n, d - 1))
    v = v / jnp.linalg.norm(v, axis=-1, keepdims=True)
    return jnp.concatenate([w[:, None], jnp.sqrt(jnp.clip(1.0 - w**2, 0.0))[:, None] * v], -1)


def householder_to(mu: jax.Array, x: jax.Array, eps: float = 1e-6) -> jax.Array:
    """Apply H = I - 2 u u^T with u = (e1 - mu) / |e1 - mu| to x (H e1 = mu, H orthogonal).

    mu: unit vectors [..., d]; x: [..., d]. Where mu = e1 already, H is the identity.
    """
    e1 = jnp.zeros_like(mu).at[..., 0].set(1.0)
    diff = e1 - mu
    norm = jnp.linalg.norm(diff, axis=-1, keepdims=True)
    u = diff / jnp.maximum(norm, eps)
    reflected = x - 2.0 * u * jnp.sum(u * x, axis=-1, keepdims=True)
    return jnp.where(norm > eps, reflected, x)


def sample_vmf(key: jax.Array, mu: jax.Array, kappa: float) -> jax.Array:
    """One draw x ~ vMF(mu_i / |mu_i|, kappa) per row of mu [n, d]: unit vectors [n, d]."""
    n, d = mu.shape
    mu = mu / (jnp.linalg.norm(mu, axis=-1, keepdims=True) + 1e-8)
    return householder_to(mu, sample_vmf_north(key, n, d, kappa))
