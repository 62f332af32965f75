"""The authors' settings (size="authors"): their network layout, the min twin target, the
sampled h, against hand-written maths."""

import dataclasses
import re

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import zsbfm
from zsbfm.agents import make_agent
from zsbfm.agents.base import Task
from zsbfm.agents.fb import fb_loss, head_gap
from zsbfm.data.samplers import Transitions
from zsbfm.nets.fb import BackwardNet, TwinForward
from zsbfm.nets.mlp import NormedMLP
from zsbfm.ops.sphere import sample_sphere


def layer_norm(x, p):
    mu, var = x.mean(-1, keepdims=True), x.var(-1, keepdims=True)
    return (x - mu) / jnp.sqrt(var + 1e-6) * p["scale"] + p["bias"]


def test_normed_mlp_is_tanh_layernorm_then_gelu_layernorm_with_orthogonal_kernels():
    net = NormedMLP((16, 16, 8), 5)
    x = jax.random.normal(jax.random.PRNGKey(0), (7, 3))
    p = net.init(jax.random.PRNGKey(1), x)["params"]
    dense = lambda x, q: x @ q["kernel"] + q["bias"]
    y = layer_norm(jnp.tanh(dense(x, p["Dense_0"])), p["LayerNorm_0"])
    y = layer_norm(nn.gelu(dense(y, p["Dense_1"])), p["LayerNorm_1"])
    y = layer_norm(nn.gelu(dense(y, p["Dense_2"])), p["LayerNorm_2"])
    np.testing.assert_allclose(net.apply({"params": p}, x), dense(y, p["Dense_3"]), rtol=1e-5, atol=1e-5)
    k = p["Dense_1"]["kernel"]  # square: orthogonal means K^T K = I
    np.testing.assert_allclose(k.T @ k, np.eye(16), atol=1e-5)


def test_mlp_arch_is_one_trunk_on_state_and_task_for_f_and_b():
    F = TwinForward(4, 3, (8,), 8, (16, 16), h_dim=2, arch="mlp", heads=2)
    obs, w = jnp.ones((5, 6)), jnp.ones((5, 4 + 2))
    params = F.init(jax.random.PRNGKey(0), obs, w)
    assert set(params["params"]["F"]) == {"trunk"}                 # no preprocessors
    assert params["params"]["F"]["trunk"]["Dense_0"]["kernel"].shape == (2, 6 + 6, 16)
    assert F.apply(params, obs, w).shape == (2, 5, 3, 4)
    B = BackwardNet(4, (8, 8), arch="mlp")
    pb = B.init(jax.random.PRNGKey(1), obs)
    assert "LayerNorm_1" in pb["params"]["NormedMLP_0"]             # LayerNorm after every hidden layer
    np.testing.assert_allclose(jnp.linalg.norm(B.apply(pb, obs), axis=-1), 2.0, rtol=1e-5)


def test_head_gap_is_the_mean_absolute_difference_of_two_heads_off_the_diagonal():
    Ms = jax.random.normal(jax.random.PRNGKey(0), (2, 6, 6))
    off = ~np.eye(6, dtype=bool)
    want = np.abs(np.asarray(Ms[0] - Ms[1]))[off].mean()
    np.testing.assert_allclose(head_gap(Ms, exclude_diag=True), want, rtol=1e-6)
    rho = jnp.arange(1.0, 7.0) / 21.0
    np.testing.assert_allclose(head_gap(Ms, rho), (np.abs(np.asarray(Ms[0] - Ms[1])) @ np.asarray(rho)).mean(),
                               rtol=1e-6)


def _batch(env, n, key):
    k1, k2, k3 = jax.random.split(key, 3)
    obs = jax.random.randint(k1, (n, 2), 1, 10).astype(jnp.float32)
    nxt = jax.random.randint(k2, (n, 2), 1, 10).astype(jnp.float32)
    return Transitions(obs=obs, action=jax.random.randint(k3, (n,), 0, 4), next_obs=nxt,
                       episode=jnp.zeros(n, jnp.int32), t=jnp.zeros(n, jnp.int32))


@pytest.mark.parametrize("twin_target", ["min", "mean"])
def test_fb_loss_uses_the_elementwise_min_or_mean_of_the_target_heads(twin_target):
    cfg = zsbfm.Config.preset("fourrooms", "fb", "authors", f_hidden=(16, 16), b_hidden=(16,), d=6,
                              twin_target=twin_target)
    env = zsbfm.make_env("fourrooms", n_train=cfg.n_train_layouts)
    agent = make_agent(cfg, env)
    state = agent.init(jax.random.PRNGKey(0))
    # a target that differs from the online parameters, so the two heads disagree
    target = jax.tree_util.tree_map(lambda p: p * 1.3, state.params)
    batch = _batch(env, 12, jax.random.PRNGKey(1))
    task = Task(z=sample_sphere(jax.random.PRNGKey(2), 12, cfg.d), h=jnp.zeros((12, 0)))
    total, metrics = agent.loss(state.params, target, batch, task, {})
    F = agent.forward_sa(state.params.F, batch.obs, batch.action, task)
    B = agent.backward(state.params.B, batch.next_obs)
    Ms = jnp.einsum("knd,md->knm", agent.target_next_F(target, batch.next_obs, task, {}),
                    agent.backward(target.B, batch.next_obs))
    combined = jnp.min(Ms, 0) if twin_target == "min" else jnp.mean(Ms, 0)
    want, _ = fb_loss(F, B, combined, cfg.gamma)
    np.testing.assert_allclose(metrics["fb_loss"], want, rtol=1e-5)
    assert float(metrics["M_head_gap"]) > 0


def test_h_noise_draws_mu_plus_sigma_eps_from_the_tables():
    cfg = zsbfm.Config.preset("fourrooms", "bfb", "authors", d=6, h_dim=3, f_hidden=(8,), b_hidden=(8,),
                              enc_layers=1, enc_embed=12, enc_mlp=8, pred_hidden=(8,))
    env = zsbfm.make_env("fourrooms", n_train=cfg.n_train_layouts)
    agent = make_agent(cfg, env)
    state = agent.init(jax.random.PRNGKey(0))
    mu = jnp.arange(state.h_table.size, dtype=jnp.float32).reshape(state.h_table.shape) / 100.0
    sigma = jnp.full_like(mu, 0.5).at[3].set(2.0)
    state = state.replace(h_table=mu, h_sigma_table=sigma)
    n = 20_000
    batch = Transitions(obs=jnp.zeros((n, 2)), action=jnp.zeros(n, jnp.int32), next_obs=jnp.zeros((n, 2)),
                        episode=jnp.full(n, 3), t=jnp.zeros(n, jnp.int32))
    h = agent.train_context(state, None, batch, jax.random.PRNGKey(5))
    np.testing.assert_allclose(h.mean(0), mu[3, 0], atol=4 * 2.0 / np.sqrt(n))
    np.testing.assert_allclose(h.std(0), 2.0, rtol=0.03)
    no_noise = dataclasses.replace(agent, cfg=cfg.replace(h_noise=False))
    np.testing.assert_array_equal(no_noise.train_context(state, None, batch, jax.random.PRNGKey(5)),
                                  jnp.broadcast_to(mu[3, 0], h.shape))


def test_authors_preset_holds_their_settings():
    c = zsbfm.Config.preset("fourrooms", "bfb", "authors")
    assert (c.f_arch, c.f_hidden, c.b_hidden, c.f_heads, c.twin_target) == ("mlp", (1024, 512, 512), (512, 512, 512), 2, "min")
    assert (c.batch_size, c.lr, c.clip_norm, c.tau, c.gamma, c.d, c.temperature, c.q_loss_coef) == \
        (1024, 3e-4, 1.0, 0.01, 0.99, 150, 350.0, 0.0)
    assert (c.h_dim, c.h_noise, c.h_standardize, c.enc_layers, c.enc_embed, c.obs_encoding) == (32, True, False, 4, 96, "unscaled")
    assert c.fb_steps == 20_000
    r = zsbfm.Config.preset("fourrooms", "rfb", "authors")
    assert (r.context_dim, r.temperature, r.kappa, r.rfb_z_states) == (150, 300.0, 50.0, "dataset")
    with pytest.raises(ValueError, match="size='authors' is invalid for env 'antwind'"):
        zsbfm.Config.preset("antwind", "fb", "authors")


@pytest.mark.parametrize("shape", [(7, 5), (5, 7), (2, 3, 6), (64, 64)])
def test_orthogonal_init_is_flax_orthogonal_without_lapack(shape):
    from zsbfm.ops.orthogonal import orthogonal

    key = jax.random.PRNGKey(3)
    ours = orthogonal()(key, shape)
    np.testing.assert_allclose(ours, nn.initializers.orthogonal()(key, shape), atol=2e-5)
    jaxpr = str(jax.make_jaxpr(lambda k: jax.vmap(lambda kk: orthogonal()(kk, shape))(k))(jax.random.split(key, 2)))
    assert not re.search(r"\bqr\b|householder|geqrf|orgqr", jaxpr)  # nothing the batched LAPACK kernels run
