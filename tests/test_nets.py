"""The network building blocks and their products (ops.matmul) against plain JAX."""

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from zsbfm.nets.mlp import Dense
from zsbfm.ops.matmul import LARGE_DIM, matmul

L = LARGE_DIM  # at and above it, matmul's backward writes transposed operands out


@pytest.mark.parametrize("x_shape, kernel_shape", [((7, 5), (5, 4)), ((3, 7, 5), (5, 4)),
                                                   ((L, L), (L, L)), ((2, L // 2, L), (L, L + 8))])
def test_matmul_has_the_gradients_of_the_plain_product(x_shape, kernel_shape):
    kx, kk, kg = jax.random.split(jax.random.PRNGKey(0), 3)
    x = jax.random.normal(kx, x_shape)
    kernel = jax.random.normal(kk, kernel_shape) / kernel_shape[0] ** 0.5
    g = jax.random.normal(kg, x_shape[:-1] + kernel_shape[1:])  # a cotangent that is not all ones

    def loss(f):
        return lambda x, k: jnp.sum(g * jnp.tanh(f(x, k)))

    want = jax.grad(loss(lambda x, k: x @ k), argnums=(0, 1))(x, kernel)
    got = jax.grad(loss(matmul), argnums=(0, 1))(x, kernel)
    np.testing.assert_allclose(matmul(x, kernel), x @ kernel, rtol=1e-6)
    for a, b in zip(got, want):
        assert a.shape == b.shape
        np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-4)


@pytest.mark.parametrize("n, i, o", [(6, 5, 3), (L, L, L)])
def test_matmul_gradients_under_vmap_of_the_kernel(n, i, o):
    """The twin heads' case: one input shared by a stack of kernels (nn.vmap, in_axes=None)."""
    x = jax.random.normal(jax.random.PRNGKey(1), (n, i))
    kernels = jax.random.normal(jax.random.PRNGKey(2), (2, i, o)) / i**0.5

    def loss(f):
        return lambda k: jnp.sum(jax.vmap(f, in_axes=(None, 0))(x, k) ** 3)

    np.testing.assert_allclose(jax.grad(loss(matmul))(kernels),
                               jax.grad(loss(lambda x, k: x @ k))(kernels), rtol=1e-4, atol=1e-4)


def test_dense_keeps_flax_dense_parameters_and_outputs():
    x = jax.random.normal(jax.random.PRNGKey(3), (4, 6))
    ours, flax_dense = Dense(3), nn.Dense(3)
    params = ours.init(jax.random.PRNGKey(4), x)
    assert jax.tree_util.tree_structure(params) == jax.tree_util.tree_structure(
        flax_dense.init(jax.random.PRNGKey(4), x))
    np.testing.assert_allclose(ours.apply(params, x), flax_dense.apply(params, x), rtol=1e-6)
