"""The FB loss's s+ estimators, gradient clipping and B's learning rate, against exact sums."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import zsbfm
from zsbfm.agents import FBAgent
from zsbfm.agents.fb import clip_by_global_norm, fb_loss_splus, ortho_loss_weighted
from zsbfm.data import collect

from test_fb import GAMMA, exact_successor_measure, tiny_grid
from tests.conftest import jit_optimised


def test_weighted_fb_loss_is_the_expectation_over_s_plus():
    """fb_loss_splus with weights rho is E_{s+ ~ rho} of the pairwise loss, elementwise."""
    k1, k2, k3, k4, k5 = jax.random.split(jax.random.PRNGKey(0), 5)
    F = jax.random.normal(k1, (2, 5, 4))
    Bn = jax.random.normal(k2, (5, 4))
    Bp = jax.random.normal(k3, (7, 4))
    T = jax.random.normal(k4, (5, 7))
    rho = jax.nn.softmax(jax.random.normal(k5, (7,)))
    loss, m = fb_loss_splus(F, Bn, Bp, T, 0.9, rho)
    F, Bn, Bp, T, rho = map(np.asarray, (F, Bn, Bp, T, rho))
    expect = 0.0
    for k in range(2):
        off = np.mean([sum(rho[j] * (F[k, i] @ Bp[j] - 0.9 * T[i, j]) ** 2 for j in range(7)) for i in range(5)])
        expect += 0.5 * off - np.mean([F[k, i] @ Bn[i] for i in range(5)])
    np.testing.assert_allclose(float(loss), expect, rtol=1e-5)
    # uniform weights: the sample mean over the m states
    l_u, _ = fb_loss_splus(*map(jnp.asarray, (F, Bn, Bp, T)), 0.9)
    l_w, _ = fb_loss_splus(*map(jnp.asarray, (F, Bn, Bp, T)), 0.9, jnp.full(7, 1 / 7))
    np.testing.assert_allclose(float(l_u), float(l_w), rtol=1e-6)


def test_weighted_ortho_loss_is_the_expectation_over_independent_pairs():
    B = jax.random.normal(jax.random.PRNGKey(1), (6, 3))
    rho = jax.nn.softmax(jax.random.normal(jax.random.PRNGKey(2), (6,)))
    Bn, r = np.asarray(B), np.asarray(rho)
    expect = sum(r[i] * r[j] * (Bn[i] @ Bn[j]) ** 2 for i in range(6) for j in range(6)) \
        - 2 * sum(r[i] * Bn[i] @ Bn[i] for i in range(6))
    np.testing.assert_allclose(float(ortho_loss_weighted(B, rho)), expect, rtol=1e-5)


def test_dataset_rho_is_the_next_state_frequency():
    env = zsbfm.make_env("fourrooms", n_train=2)
    ds = collect(env, jax.random.PRNGKey(0), env.contexts("train"), 5)
    agent = FBAgent(zsbfm.Config.preset("fourrooms", "fb", splus="exact", n_train_layouts=2), env)
    rho = np.asarray(agent.dataset_stats(ds)["rho"])
    nxt = np.asarray(ds.obs[:, 1:]).reshape(-1, 2).astype(int)
    i = 11 * nxt[0, 1] + nxt[0, 0]
    np.testing.assert_allclose(rho.sum(), 1.0, rtol=1e-6)
    np.testing.assert_allclose(rho[i], np.mean((nxt[:, 0] == nxt[0, 0]) & (nxt[:, 1] == nxt[0, 1])), rtol=1e-6)
    walls = np.asarray(env.contexts("train").walls).all(0).reshape(-1)   # walls in every layout
    assert rho[walls].sum() == 0


# "exact" is the gridworld presets' estimator; "states" (~35 s) runs in `make test-all`
@pytest.mark.parametrize("splus", ["exact", pytest.param("states", marks=pytest.mark.slow)])
def test_learned_measure_matches_closed_form_with_independent_s_plus(splus):
    """The exact-expectation and independent-states estimators learn the same closed-form
    measure as the batch estimator (test_fb)."""
    env, ctxs, cells = tiny_grid()
    ds = collect(env, jax.random.PRNGKey(0), ctxs, 400)
    cfg = zsbfm.Config.preset("fourrooms", "fb", d=16, f_pre_hidden=(64,), f_pre_out=64,
                              f_hidden=(128,), b_hidden=(64,), batch_size=256, gamma=GAMMA,
                              lr=1e-3, target_policy="uniform", splus=splus, splus_batch=256)
    agent = FBAgent(cfg, env)
    state = jax.jit(agent.init)(jax.random.PRNGKey(1))
    train = jit_optimised(lambda s, k: agent.run_steps(s, ds, jax.random.split(k, 1000), 0))
    state, _ = train(state, jax.random.PRNGKey(2))
    M = exact_successor_measure(cells, GAMMA)
    S = len(cells)
    rho = np.asarray(FBAgent(dataclasses.replace(cfg, splus="exact"), env).dataset_stats(ds)["rho"])
    rho = rho[[11 * y + x for x, y in cells]]
    obs = jnp.asarray(cells, jnp.float32)
    from zsbfm.agents import Task

    z = jnp.ones((S, 16)) * 1.0
    F = agent.forward(state.params.F, obs, Task(z=z, h=jnp.zeros((S, 0)))).mean(0)
    B = agent.backward(state.params.B, obs)
    M_hat = np.asarray(jnp.einsum("sad,td->sat", F, B)).reshape(S * 4, S) * rho[None]
    err = np.linalg.norm(M_hat - M) / np.linalg.norm(M)
    trivial = np.linalg.norm(M - M.mean(0, keepdims=True)) / np.linalg.norm(M)
    assert err < 0.1, f"splus={splus}: relative error {err:.3f} (the row mean gives {trivial:.3f})"


def test_clip_by_global_norm():
    g = {"a": jnp.array([3.0, 0.0]), "b": jnp.array([[4.0]])}             # |g| = 5
    c = clip_by_global_norm(g, 1.0)
    np.testing.assert_allclose(float(jnp.sqrt(sum(jnp.sum(x**2) for x in jax.tree_util.tree_leaves(c)))), 1.0, rtol=1e-5)
    np.testing.assert_allclose(np.asarray(c["a"]), [0.6, 0.0], rtol=1e-5)
    for max_norm in (0.0, 10.0):  # off, and a norm under the cap: unchanged
        same = clip_by_global_norm(g, max_norm)
        np.testing.assert_array_equal(np.asarray(same["a"]), np.asarray(g["a"]))


def test_lr_B_sets_the_backward_step_size():
    """Adam on a constant gradient moves every parameter by lr per step: F by lr, B by lr_B."""
    env = zsbfm.make_env("fourrooms", n_train=1)
    cfg = zsbfm.Config.preset("fourrooms", "fb", d=4, f_pre_hidden=(4,), f_pre_out=4, f_hidden=(4,),
                              b_hidden=(4,), lr=1e-2, lr_B=1e-4)
    agent = FBAgent(cfg, env)
    state = agent.init(jax.random.PRNGKey(0))
    ones = jax.tree_util.tree_map(jnp.ones_like, state.params)
    params, _ = jax.jit(agent.apply_grads)(state.params, state.opt_state, ones)  # one compile, not one per op
    step = jax.tree_util.tree_map(lambda a, b: jnp.max(jnp.abs(a - b)), params, state.params)
    np.testing.assert_allclose(max(jax.tree_util.tree_leaves(step.F)), 1e-2, rtol=1e-3)
    np.testing.assert_allclose(max(jax.tree_util.tree_leaves(step.B)), 1e-4, rtol=1e-3)


def test_eval_ema_evaluates_the_running_mean_then_the_exponential_average_of_the_updates():
    """With eval_ema = r, evaluation reads a_n = a_{n-1} + max(r, 1/n) (p_n - a_{n-1}) over
    the online parameters p_1, p_2, ... after each update: the plain mean of p_1..p_n while
    n <= 1/r, then an exponential average. Training is unchanged by it."""
    env = zsbfm.make_env("fourrooms", n_train=2)
    ds = collect(env, jax.random.PRNGKey(0), env.contexts("train"), 4)
    small = dict(d=4, f_pre_hidden=(4,), f_pre_out=4, f_hidden=(4,), b_hidden=(4,), batch_size=16)
    off = FBAgent(zsbfm.Config.preset("fourrooms", "fb", **small), env)
    on = FBAgent(zsbfm.Config.preset("fourrooms", "fb", eval_ema=0.25, **small), env)
    s_off, s_on = off.init(jax.random.PRNGKey(1)), on.init(jax.random.PRNGKey(1))
    assert s_off.average is None and int(s_on.average.n) == 0
    up_off, up_on = jax.jit(off.update), jax.jit(on.update)
    online, expect = [], None
    for n in range(1, 7):
        k = jax.random.PRNGKey(10 + n)
        s_off, _ = up_off(s_off, ds, k)
        s_on, _ = up_on(s_on, ds, k)
        assert off.eval_params(s_off) is s_off.params
        p = [np.asarray(x) for x in jax.tree_util.tree_leaves(s_on.params.F)]
        online.append(p)
        if n <= 4:    # 1/n >= r: the mean of every update so far
            expect = [np.mean([o[i] for o in online], 0) for i in range(len(p))]
        else:         # the exponential average at rate r from the mean of the first four
            expect = [0.75 * e + 0.25 * x for e, x in zip(expect, p)]
        got = jax.tree_util.tree_leaves(on.eval_params(s_on).F)
        for g, e in zip(got, expect):
            np.testing.assert_allclose(np.asarray(g), e, rtol=1e-5, atol=1e-6)
    assert int(s_on.average.n) == 6
    same = jax.tree_util.tree_map(np.array_equal, s_off.params, s_on.params)  # training unchanged
    assert all(jax.tree_util.tree_leaves(same))
    assert not np.array_equal(got[0], jax.tree_util.tree_leaves(s_on.params.F)[0])


@pytest.mark.parametrize("field,value,match", [
    ("splus", "cells", "Config.splus='cells'"),
    ("clip_norm", -1.0, "Config.clip_norm=-1.0"),
    ("lr_B", -1e-3, "Config.lr_B=-0.001"),
    ("eval_every", -1, "Config.eval_every=-1"),
    ("eval_ema", 1.0, "Config.eval_ema=1.0"),
    ("eval_protocols", "dense", "Config.eval_protocols='dense'"),
])
def test_invalid_lever_values_raise_naming_the_field(field, value, match):
    with pytest.raises(ValueError, match=match):
        zsbfm.Config(**{field: value})


@pytest.mark.parametrize("field", sorted(zsbfm.config.NONNEGATIVE_INTS))
def test_nonnegative_int_fields_take_zero_and_reject_negatives_and_bools(field):
    zsbfm.Config(**{field: 0})
    for value in (-1, True, 1.5):  # True is an int to Python; it must not pass as 1
        with pytest.raises(ValueError, match=f"Config.{field}={value!r} .*non-negative integer"):
            zsbfm.Config(**{field: value})


def test_positive_int_fields_reject_bools():
    for field in ("steps", "expert_steps"):
        with pytest.raises(ValueError, match=f"Config.{field}=True .*positive integer"):
            zsbfm.Config(**{field: True})


def test_exact_splus_needs_a_finite_state_env():
    with pytest.raises(ValueError, match="Config.splus='exact'"):
        zsbfm.Config.preset("pointmass", "fb", splus="exact")


def test_q_loss_matches_its_definition():
    """q_loss: sum_k mean_i (F_k^T z - [B(s')^T C^-1 z + gamma min_k' Fbar_k'^T z])^2, C = E_rho B B^T."""
    from zsbfm.agents.fb import q_loss

    ks = jax.random.split(jax.random.PRNGKey(3), 6)
    F, Ft = jax.random.normal(ks[0], (2, 5, 3)), jax.random.normal(ks[1], (2, 5, 3))
    Bn, Bp, z = jax.random.normal(ks[2], (5, 3)), jax.random.normal(ks[3], (9, 3)), jax.random.normal(ks[4], (5, 3))
    rho = jax.nn.softmax(jax.random.normal(ks[5], (9,)))
    got = float(q_loss(F, Ft, Bn, Bp, z, 0.9, rho))
    F, Ft, Bn, Bp, z, rho = map(lambda a: np.asarray(a, np.float64), (F, Ft, Bn, Bp, z, rho))
    C = sum(rho[j] * np.outer(Bp[j], Bp[j]) for j in range(9))
    C = C + 1e-4 * np.trace(C) / 3 * np.eye(3)
    expect = 0.0
    for k in range(2):
        errs = [(F[k, i] @ z[i] - (Bn[i] @ np.linalg.solve(C, z[i]) + 0.9 * min(Ft[0, i] @ z[i], Ft[1, i] @ z[i]))) ** 2
                for i in range(5)]
        expect += np.mean(errs)
    np.testing.assert_allclose(got, expect, rtol=1e-4)
