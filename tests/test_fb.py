"""FB against exact quantities: the closed-form successor measure on a tiny grid."""

import jax
import jax.numpy as jnp
import numpy as np

import zsbfm
from zsbfm.agents import FBAgent, Task, fb_loss, ortho_loss
from zsbfm.data import collect
from zsbfm.envs import GridContext
from zsbfm.envs.gridworld import ACTION_DELTAS
from tests.conftest import jit_optimised

GAMMA = 0.8


def tiny_grid():
    """A 3x3 open room (cells x, y in 1..3) inside the 11x11 fourrooms frame."""
    env = zsbfm.make_env("fourrooms", n_train=1, episode_len=50)
    walls = np.ones((11, 11), bool)
    walls[1:4, 1:4] = False
    cells = [(x, y) for y in range(1, 4) for x in range(1, 4)]
    return env, GridContext(walls=jnp.asarray(walls)[None]), cells


def exact_successor_measure(cells, gamma):
    """M[(s, a), s+] = sum_t gamma^t P(s_{t+1} = s+ | s, a) under the uniform policy:
    M = P_sa (I - gamma P_pi)^-1 with P_pi = mean_a P_sa."""
    idx = {c: i for i, c in enumerate(cells)}
    S = len(cells)
    P = np.zeros((S * 4, S))
    for i, (x, y) in enumerate(cells):
        for a, (dx, dy) in enumerate(ACTION_DELTAS):
            nxt = (x + dx, y + dy)
            P[i * 4 + a, idx.get(nxt, i)] = 1.0
    P_pi = P.reshape(S, 4, S).mean(1)
    return P @ np.linalg.inv(np.eye(S) - gamma * P_pi)


def test_learned_measure_matches_closed_form():
    env, ctxs, cells = tiny_grid()
    ds = collect(env, jax.random.PRNGKey(0), ctxs, 400)
    cfg = zsbfm.Config.preset("fourrooms", "fb", d=16, f_pre_hidden=(64,), f_pre_out=64,
                              f_hidden=(128,), b_hidden=(64,), batch_size=256, gamma=GAMMA,
                              lr=1e-3, target_policy="uniform", splus="batch", q_loss_coef=0.0,
                              clip_norm=0.0, tau=0.05, f_heads=1)  # settings pinned: the maths, not the preset
    agent = FBAgent(cfg, env)  # the paper's FB loss: s+ from the batch, no Q-loss
    state = jax.jit(agent.init)(jax.random.PRNGKey(1))
    train = jit_optimised(lambda s, k: jax.lax.scan(lambda s, k: agent.update(s, ds, k), s,
                                                   jax.random.split(k, 1000)))  # relative error ~0.03-0.05 from 500 updates on
    state, _ = train(state, jax.random.PRNGKey(2))

    M = exact_successor_measure(cells, GAMMA)
    S = len(cells)
    # rho: the law of the next states the loss pairs F with (uniform over stored s').
    nxt = np.asarray(ds.obs[:, 1:]).reshape(-1, 2).astype(int)
    rho = np.array([np.mean((nxt[:, 0] == x) & (nxt[:, 1] == y)) for x, y in cells])
    obs = jnp.asarray(cells, jnp.float32)
    trivial = np.linalg.norm(M - M.mean(0, keepdims=True)) / np.linalg.norm(M)
    for i in range(3):  # the uniform policy's measure must not depend on z
        z = np.asarray(jax.random.normal(jax.random.PRNGKey(10 + i), (16,)))
        z = jnp.asarray(4.0 * z / np.linalg.norm(z))
        task = Task(z=jnp.broadcast_to(z, (S, 16)), h=jnp.zeros((S, 0)))
        F = agent.forward(state.params.F, obs, task).mean(0)            # [S, A, d]
        B = agent.backward(state.params.B, obs)                           # [S, d]
        M_hat = np.asarray(jnp.einsum("sad,td->sat", F, B)).reshape(S * 4, S) * rho[None]
        err = np.linalg.norm(M_hat - M) / np.linalg.norm(M)
        assert err < 0.1, f"relative error {err:.3f} (predicting the row mean gives {trivial:.3f})"
        # total mass of the discounted measure is 1 / (1 - gamma)
        assert abs(M_hat.sum(1).mean() - 1 / (1 - GAMMA)) < 0.1 / (1 - GAMMA)


def test_fb_loss_matches_elementwise_definition():
    k1, k2, k3 = jax.random.split(jax.random.PRNGKey(0), 3)
    F = jax.random.normal(k1, (2, 6, 4))
    B = jax.random.normal(k2, (6, 4))
    T = jax.random.normal(k3, (6, 6))
    loss, _ = fb_loss(F, B, T, 0.9)
    F, B, T = map(np.asarray, (F, B, T))
    expect = 0.0
    for k in range(2):
        off = [(F[k, i] @ B[j] - 0.9 * T[i, j]) ** 2 for i in range(6) for j in range(6) if i != j]
        expect += 0.5 * np.mean(off) - np.mean([F[k, i] @ B[i] for i in range(6)])
    np.testing.assert_allclose(float(loss), expect, rtol=1e-5)


def test_ortho_loss_is_minimal_for_orthogonal_rows():
    d = 8
    eye = jnp.eye(d) * jnp.sqrt(d)  # rows orthogonal, norm sqrt(d)
    rand = jax.random.normal(jax.random.PRNGKey(0), (d, d))
    rand = rand / jnp.linalg.norm(rand, axis=1, keepdims=True) * jnp.sqrt(d)
    np.testing.assert_allclose(float(ortho_loss(eye)), -2.0 * d, rtol=1e-5)
    assert float(ortho_loss(rand)) > float(ortho_loss(eye))


def test_reward_inference_of_a_goal_indicator_is_B_of_the_goal():
    env = zsbfm.make_env("fourrooms")
    cfg = zsbfm.Config.preset("fourrooms", "fb", d=8, f_pre_hidden=(8,), f_pre_out=8, f_hidden=(8,),
                              b_hidden=(8,))
    agent = FBAgent(cfg, env)
    params = agent.eval_params(agent.init(jax.random.PRNGKey(0)))
    obs = jnp.array([[1.0, 1.0], [8.0, 8.0], [2.0, 8.0], [8.0, 8.0]])
    reward = jnp.array([0.0, 1.0, 0.0, 1.0])
    z_r = agent.reward_task(params, obs, reward, None).z
    z_g = agent.goal_task(params, jnp.array([8.0, 8.0]), None).z
    np.testing.assert_allclose(np.asarray(z_r), np.asarray(z_g), rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(float(jnp.linalg.norm(z_g)), np.sqrt(8), rtol=1e-5)


def test_z_sampling_mixes_with_independent_keys():
    env = zsbfm.make_env("fourrooms", n_train=2)
    ds = collect(env, jax.random.PRNGKey(0), env.contexts("train"), 10)
    cfg = zsbfm.Config.preset("fourrooms", "fb", d=8, f_pre_hidden=(8,), f_pre_out=8, f_hidden=(8,),
                              b_hidden=(8,), batch_size=2000, z_mix=0.5)
    agent = FBAgent(cfg, env)
    state = agent.init(jax.random.PRNGKey(0))
    from zsbfm.data import sample_transitions

    batch = sample_transitions(jax.random.PRNGKey(1), ds, 2000)
    z = np.asarray(agent.train_z(state, ds, batch, jnp.zeros((2000, 0)), jax.random.PRNGKey(2)))
    np.testing.assert_allclose(np.linalg.norm(z, axis=1), np.sqrt(8), rtol=1e-4)
    # B(s) of the 121 grid cells is a finite set; Gaussian draws never hit it.
    cells = jnp.stack(jnp.meshgrid(jnp.arange(11.0), jnp.arange(11.0)), -1).reshape(-1, 2)
    Bset = np.asarray(agent.backward(state.params.B, cells))
    from_B = np.min(np.linalg.norm(z[:, None] - Bset[None], axis=-1), axis=1) < 1e-4
    assert 0.45 < from_B.mean() < 0.55


def test_onehot_encoding_is_the_one_hots_of_x_and_y():
    """obs_encoding="onehot": the concatenated one-hots of x and y."""
    env = zsbfm.make_env("fourrooms", n_train=1)
    cells = jnp.asarray([(x, y) for x in range(11) for y in range(11)], jnp.float32)
    xy = FBAgent(zsbfm.Config.preset("fourrooms", "fb"), env).obs_features(cells[13:14])
    np.testing.assert_array_equal(np.flatnonzero(np.asarray(xy[0])), [1, 11 + 2])   # (1, 2)


_BLAS_PROBE = """
import os, sys
import jax.numpy as jnp
import scipy.linalg  # loaded before zsbfm: threadpoolctl, not the variable, must limit it
import zsbfm
from threadpoolctl import threadpool_info
jnp.linalg.solve(jnp.eye(4) + 1.0, jnp.ones(4)).block_until_ready()  # scipy's LAPACK
print(os.environ["OPENBLAS_NUM_THREADS"], sorted({i["num_threads"] for i in threadpool_info() if i["internal_api"] == "openblas"}))
"""


def test_import_uses_one_openblas_thread_unless_the_user_set_one():
    """The Q-loss's solve runs OpenBLAS inside XLA's threads: import zsbfm limits it to one
    thread (zsbfm/cpu_tuning.py), and leaves a user's OPENBLAS_NUM_THREADS alone."""
    import os
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    out = subprocess.run([sys.executable, "-c", _BLAS_PROBE], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.split("\n")[-2] == "1 [1]"
    out = subprocess.run([sys.executable, "-c", _BLAS_PROBE], env={**env, "OPENBLAS_NUM_THREADS": "2"},
                         capture_output=True, text=True, check=True)
    assert out.stdout.split("\n")[-2] == "2 [2]"


def test_ynnpack_off_is_an_option_this_xla_accepts_and_keeps_the_maths(monkeypatch):
    """zsbfm.cpu_tuning.compiler_options turns XLA's YNNPACK fusions off for training chunks
    (not under the tests' optimisation level 0): this XLA must accept the option, and the
    compiled update must compute what the default compile does."""
    from zsbfm.cpu_tuning import YNN_OPTION, compiler_options

    monkeypatch.setenv("XLA_FLAGS", "--xla_backend_optimization_level=0")
    assert compiler_options() == {}
    monkeypatch.setenv("XLA_FLAGS", "")
    assert compiler_options() == {YNN_OPTION: ""}

    k1, k2, k3 = jax.random.split(jax.random.PRNGKey(0), 3)
    x, w1, w2 = (jax.random.normal(k, s) for k, s in zip((k1, k2, k3), ((256, 256), (256, 256), (256, 256))))
    f = lambda x, w1, w2: jax.grad(lambda w: jnp.sum(jnp.tanh(x @ w) @ w2))(w1)
    lowered = jax.jit(f).lower(x, w1, w2)
    default = lowered.compile()(x, w1, w2)
    off = lowered.compile(compiler_options={YNN_OPTION: ""})  # an unknown option or value raises
    np.testing.assert_allclose(off(x, w1, w2), default, rtol=1e-4, atol=1e-4)


_THREEFRY_PROBE = """
import sys
import jax
if sys.argv[1] == "zsbfm":
    import zsbfm  # noqa: F401  (unrolls threefry on the CPU)
key = jax.random.PRNGKey(7)
draw = jax.jit(lambda k: (jax.random.bits(k, (5,)), jax.random.normal(jax.random.split(k)[1], (3,))))
print(" while(" in draw.lower(key).compile().as_text(), *jax.device_get(draw(key))[0], *jax.device_get(draw(key))[1])
"""


def test_import_unrolls_threefry_and_keeps_every_random_bit():
    """import zsbfm lowers threefry2x32 without JAX's CPU while loop (zsbfm/cpu_tuning.py):
    the compiled draw holds no loop, and its bits are those of JAX's own lowering."""
    import subprocess
    import sys

    run = lambda mode: subprocess.run([sys.executable, "-c", _THREEFRY_PROBE, mode], capture_output=True,
                                      text=True, check=True).stdout.split()
    jax_own, ours = run("jax"), run("zsbfm")
    assert jax_own[0] == "True" and ours[0] == "False"  # the loop is there without zsbfm, gone with it
    assert ours[1:] == jax_own[1:]


def test_project_to_sphere_has_a_finite_gradient_at_zero():
    """d|x|/dx = x / |x| is 0/0 at x = 0; the projection's gradient there must be finite
    (and equal the plain norm's away from 0)."""
    from zsbfm.ops.sphere import project_to_sphere

    g0 = jax.grad(lambda x: project_to_sphere(x).sum())(jnp.zeros(4))
    assert np.all(np.isfinite(np.asarray(g0)))
    x = jnp.array([0.3, -1.2, 0.5, 2.0])
    plain = lambda x: (2.0 * x / (jnp.linalg.norm(x) + 1e-8)).sum()
    np.testing.assert_allclose(np.asarray(jax.grad(lambda x: project_to_sphere(x).sum())(x)),
                               np.asarray(jax.grad(plain)(x)), rtol=1e-6)


def test_coordinate_inputs_with_the_exact_splus_give_finite_updates():
    """Under raw and unscaled (x, y) the corner cell (0, 0), a wall that the exact s+
    expectation still evaluates at weight 0, is the zero input: B there is 0 at
    initialisation, and the sphere projection's gradient must not turn that into NaN."""
    env = zsbfm.make_env("fourrooms", n_train=2)
    ds = collect(env, jax.random.PRNGKey(0), env.contexts("train"), 4)
    for enc in ("raw", "unscaled"):
        cfg = zsbfm.Config.preset("fourrooms", "fb", d=8, f_pre_hidden=(8,), f_pre_out=8,
                                  f_hidden=(8,), b_hidden=(8,), batch_size=16, obs_encoding=enc)
        assert cfg.splus == "exact"
        agent = FBAgent(cfg, env)
        state, metrics = agent.update(agent.init(jax.random.PRNGKey(1)), ds, jax.random.PRNGKey(2))
        leaves = jax.tree_util.tree_leaves(state.params)
        assert all(np.all(np.isfinite(np.asarray(p))) for p in leaves), enc
        assert np.isfinite(float(metrics["fb_loss"])), enc
