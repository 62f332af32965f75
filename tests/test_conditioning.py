"""How the context h conditions F (Config.h_cond): FiLM against the plain concat wiring."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax.traverse_util import flatten_dict, unflatten_dict

import zsbfm
from zsbfm.agents import Task, make_agent
from zsbfm.nets.fb import ForwardNet
from zsbfm.nets.mlp import FiLM

D, H, OBS = 8, 3, 5


def nets(n_actions, h_in_sa=True):
    kw = dict(d=D, n_actions=n_actions, pre_hidden=(16,), pre_out=16, hidden=(32, 32),
              h_dim=H, h_in_sa=h_in_sa)
    return ForwardNet(**kw, h_cond="concat"), ForwardNet(**kw, h_cond="film")


def inputs(n=6, action_dim=0):
    k = jax.random.split(jax.random.PRNGKey(0), 3)
    obs = jax.random.normal(k[0], (n, OBS))
    z = jax.random.normal(k[1], (n, D))
    h = jax.nn.one_hot(jnp.arange(n) % H, H)
    a = jax.random.uniform(k[2], (n, action_dim), minval=-1, maxval=1) if action_dim else None
    return obs, z, h, a


def without_film(params):
    """The FiLM network's parameters less its FiLM layers: a concat network's parameters."""
    flat = flatten_dict(params)
    return unflatten_dict({k: v for k, v in flat.items() if not any(p.startswith("film_") for p in k)})


@pytest.mark.parametrize("n_actions,action_dim", [(4, 0), (0, 2)])
def test_film_starts_as_the_identity_modulation_of_concat(n_actions, action_dim):
    concat, film = nets(n_actions)
    obs, z, h, a = inputs(action_dim=action_dim)
    w = jnp.concatenate([z, h], -1)
    p_film = film.init(jax.random.PRNGKey(1), obs, w, a)
    p_concat = without_film(p_film)
    # same tree as a freshly initialised concat network (the layers FiLM adds are extra)
    assert (jax.tree_util.tree_structure(p_concat)
            == jax.tree_util.tree_structure(concat.init(jax.random.PRNGKey(1), obs, w, a)))
    n_film = sum(1 for k in flatten_dict(p_film) if any(p.startswith("film_") for p in k))
    assert n_film == 2 * (1 + 1 + 2)  # kernel + bias of pre_sa, pre_sw (1 layer), trunk (2)
    np.testing.assert_array_equal(film.apply(p_film, obs, w, a), concat.apply(p_concat, obs, w, a))


@pytest.mark.parametrize("n_actions,action_dim", [(4, 0), (0, 2)])
def test_film_layers_make_F_depend_on_h_multiplicatively(n_actions, action_dim):
    """With h kept out of the inputs (h_in_sa off, and pre_sw's input weights of h zeroed),
    F ignores h at initialisation; with the FiLM layers' weights perturbed, the FiLM layers
    alone carry h: different h give different F at the same (s, a, z)."""
    _, film = nets(n_actions, h_in_sa=False)
    obs, z, h, a = inputs(action_dim=action_dim)
    obs, z = jnp.broadcast_to(obs[:1], obs.shape), jnp.broadcast_to(z[:1], z.shape)
    a = None if a is None else jnp.broadcast_to(a[:1], a.shape)
    w = jnp.concatenate([z, h], -1)
    params = film.init(jax.random.PRNGKey(1), obs, w, a)
    flat = flatten_dict(params)
    # zero the weights by which h enters as an input of pre_sw (its last H input rows)
    k0 = ("params", "pre_sw", "Dense_0", "kernel")
    flat[k0] = flat[k0].at[-H:].set(0.0)
    out_init = film.apply(unflatten_dict(flat), obs, w, a)
    np.testing.assert_allclose(out_init, jnp.broadcast_to(out_init[:1], out_init.shape), atol=1e-6)
    keys = jax.random.split(jax.random.PRNGKey(2), len(flat))
    for (k, v), kk in zip(list(flat.items()), keys):
        if any(p.startswith("film_") for p in k):
            flat[k] = 0.3 * jax.random.normal(kk, v.shape)
    out = np.asarray(film.apply(unflatten_dict(flat), obs, w, a))
    for i in range(1, H):  # rows 0..H-1 differ only in h
        assert np.abs(out[i] - out[0]).max() > 1e-2


def test_film_modulation_is_scale_and_shift_of_h():
    u = jax.random.normal(jax.random.PRNGKey(0), (4, 6))
    c = jax.nn.one_hot(jnp.array([0, 1, 2, 0]), 3)
    layer = FiLM()
    p = layer.init(jax.random.PRNGKey(1), u, c)
    np.testing.assert_array_equal(layer.apply(p, u, c), u)
    W = jax.random.normal(jax.random.PRNGKey(2), (3, 12))
    p = {"params": {"Dense_0": {"kernel": W, "bias": jnp.zeros(12)}}}
    gamma, beta = W[:, :6], W[:, 6:]   # one-hot c selects a row: per-context scale and shift
    expect = (1 + gamma[jnp.array([0, 1, 2, 0])]) * u + beta[jnp.array([0, 1, 2, 0])]
    np.testing.assert_allclose(layer.apply(p, u, c), expect, rtol=1e-6)


@pytest.mark.parametrize("n_actions,action_dim", [(4, 0), (0, 2)])
def test_outer_is_a_per_context_state_embedding(n_actions, action_dim):
    """h_cond="outer" with a one-hot h = e_k is the concat network whose pre_sa first-layer
    weights of the state are W_x + W_k, W_k the rows of the outer product's block k:
    a separate linear embedding of the state per context."""
    kw = dict(d=D, n_actions=n_actions, pre_hidden=(16,), pre_out=16, hidden=(32,), h_dim=H, h_in_sa=True)
    outer, concat = ForwardNet(**kw, h_cond="outer"), ForwardNet(**kw, h_cond="concat")
    obs, z, h, a = inputs(action_dim=action_dim)
    w = jnp.concatenate([z, h], -1)
    p = flatten_dict(outer.init(jax.random.PRNGKey(1), obs, w, a))
    k0 = ("params", "pre_sa", "Dense_0", "kernel")
    n_sa = OBS + action_dim                      # pre_sa input: [s; a], h, then s (x) h
    kernel = p[k0]
    assert kernel.shape[0] == n_sa + H + OBS * H
    W_sa, W_h, W_outer = kernel[:n_sa], kernel[n_sa:n_sa + H], kernel[n_sa + H:].reshape(OBS, H, -1)
    for k in range(H):
        q = dict(p)
        W_s = W_sa.at[:OBS].add(W_outer[:, k])
        q[k0] = jnp.concatenate([W_s, W_h], 0)
        rows = np.flatnonzero(np.asarray(h[:, k]) == 1)
        got = outer.apply(unflatten_dict(p), obs[rows], w[rows], None if a is None else a[rows])
        want = concat.apply(unflatten_dict(q), obs[rows], w[rows], None if a is None else a[rows])
        np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-5)


def test_h_cond_is_validated_and_reaches_the_agent():
    with pytest.raises(ValueError, match=r"Config.h_cond='gate'.*'concat', 'film'"):
        zsbfm.Config.preset("fourrooms", "oracle", h_cond="gate")
    cfg = zsbfm.Config.preset("fourrooms", "oracle", n_train_layouts=2, h_cond="film")
    env = zsbfm.make_env("fourrooms", n_train=2)
    agent = make_agent(cfg, env)
    assert agent.F_net.h_cond == "film" and agent.F_net.h_dim == 2
    state = agent.init(jax.random.PRNGKey(0))
    assert any("film_0" in "/".join(k) for k in flatten_dict(state.params.F))
    # FB (no context) is unaffected by h_cond: no FiLM layers, same params as concat
    fb = make_agent(dataclasses.replace(cfg, algo="fb"), env)
    assert not any("film_0" in "/".join(k) for k in flatten_dict(fb.init(jax.random.PRNGKey(0)).params.F))
    task = Task(z=jnp.ones((1, cfg.d)), h=jnp.asarray([[0.0, 1.0]]))
    assert agent.q_values(state.params, jnp.asarray([[1.0, 1.0]]), task).shape == (1, env.n_actions)


@pytest.mark.parametrize("arch", ["reference", "normed_trunk"])
def test_f_arch_matches_its_layers_written_out(arch):
    """F's layer layout against numpy: "reference" (controllable_agent's ForwardMap) is
    pre = relu(W2 tanh(LN(W1 x))), trunk = W4 relu(W3 [pre_sa; pre_sw]); "normed_trunk"
    has linear preprocessor outputs and LN -> tanh on the trunk's first layer."""
    net = ForwardNet(d=D, n_actions=4, pre_hidden=(16,), pre_out=16, hidden=(32,), arch=arch)
    obs, z, _, _ = inputs()
    params = net.init(jax.random.PRNGKey(1), obs, z)["params"]
    dense = lambda p, x: x @ np.asarray(p["kernel"]) + np.asarray(p["bias"])

    def ln(p, x):
        x = (x - x.mean(-1, keepdims=True)) / np.sqrt(x.var(-1, keepdims=True) + 1e-6)
        return x * np.asarray(p["scale"]) + np.asarray(p["bias"])

    relu = lambda x: np.maximum(x, 0)
    ref = arch == "reference"

    def pre(p, x):
        y = dense(p["Dense_1"], np.tanh(ln(p["LayerNorm_0"], dense(p["Dense_0"], x))))
        return relu(y) if ref else y

    o, w = np.asarray(obs), np.asarray(z)
    e = np.concatenate([pre(params["pre_sa"], o), pre(params["pre_sw"], np.concatenate([o, w], -1))], -1)
    t = params["trunk"]
    u = dense(t["Dense_0"], e)
    hid = relu(u) if ref else np.tanh(ln(t["LayerNorm_0"], u))
    want = dense(t["Dense_1"], hid).reshape(len(o), 4, D)
    np.testing.assert_allclose(np.asarray(net.apply({"params": params}, obs, z)), want, rtol=1e-4, atol=1e-4)


def test_saved_configs_without_f_arch_load_as_normed_trunk():
    d = zsbfm.Config.preset("fourrooms", "fb").to_dict()
    assert d["f_arch"] == "reference"
    del d["f_arch"]
    legacy = zsbfm.Config.from_dict(d)
    assert legacy.f_arch == "normed_trunk"
    env = zsbfm.make_env("fourrooms")
    for cfg, has_norm in ((legacy, True), (zsbfm.Config.from_dict({**d, "f_arch": "reference"}), False)):
        trunk = make_agent(cfg, env).init(jax.random.PRNGKey(0)).params.F["params"]["F"]["trunk"]
        assert ("LayerNorm_0" in trunk) == has_norm  # the agent builds F with cfg.f_arch
    with pytest.raises(ValueError, match="Config.f_arch='mlp'"):
        zsbfm.Config.preset("fourrooms", "fb", f_arch="mlp")
