"""Randomized Pointmass: physics against the closed form, walls never entered, mazes
against an independent BFS check, behaviour data and rendering."""

from collections import deque

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import zsbfm
from zsbfm.data import collect
from zsbfm.envs.pointmass import (ACCEL, DAMPING, DT, SUBSTEPS, UNIT, MazeContext, PointMass,
                                  fixed_mazes)
from tests.conftest import jit_optimised


def test_free_motion_matches_closed_form():
    """No walls nearby: constant force a from rest, v(t) = (f/k)(1 - e^{-kt}),
    x(t) = x0 + (f/k) t - (f/k)(1 - e^{-kt}) / k."""
    env = PointMass(n_train=1)
    walls = np.ones((8, 8), bool)
    walls[1:7, 1:7] = False
    ctx = MazeContext(walls=jnp.asarray(walls))
    a = np.array([0.3, -0.2])
    x0 = np.array([16.0, 16.0])
    state = env.reset(jax.random.PRNGKey(0), ctx, start=jnp.asarray(x0))
    f, k = ACCEL * a, DAMPING
    for n in range(1, 11):
        state = env.step(state, jnp.asarray(a))
        t = n * SUBSTEPS * DT
        x = x0 + f / k * t - f / k * (1 - np.exp(-k * t)) / k
        v = f / k * (1 - np.exp(-k * t))
        np.testing.assert_allclose(np.asarray(state.obs), x, atol=1e-4)
        np.testing.assert_allclose(np.asarray(state.inner.vel), v, atol=1e-4)


def test_full_force_random_actions_never_enter_a_wall():
    env = PointMass(n_train=10)
    ctxs = env.contexts("train")
    ds = collect(env, jax.random.PRNGKey(0), ctxs, 8, policy=lambda k, o: jnp.sign(env.random_action(k)))
    pos = np.asarray(ds.obs)                                              # [E, T+1, 2]
    walls = np.asarray(ctxs.walls)[np.asarray(ds.context_id)]             # [E, 8, 8]
    cells = np.floor(pos / UNIT).astype(int)
    assert (cells >= 1).all() and (cells <= 6).all(), "left the maze interior"
    e = np.arange(len(pos))[:, None]
    assert not walls[e, cells[..., 1], cells[..., 0]].any(), "a position inside a wall cell"
    # and the motion is not trivially stuck: the mass travels
    assert np.abs(np.diff(pos, axis=1)).sum(-1).mean() > 0.3


def independent_bfs(open_cells, start):
    dist = {start: 0}
    q = deque([start])
    while q:
        x, y = q.popleft()
        for nx, ny in ((x + 1, y), (x - 1, y), (x, y + 1), (x, y - 1)):
            if open_cells[ny][nx] and (nx, ny) not in dist:
                dist[(nx, ny)] = dist[(x, y)] + 1
                q.append((nx, ny))
    return dist


def test_fixed_mazes_are_valid_and_disjoint():
    train, test = fixed_mazes(30)
    assert train.shape == (30, 8, 8) and test.shape == (20, 8, 8)
    keys = [w.tobytes() for w in np.concatenate([train, test])]
    assert len(set(keys)) == 50, "duplicates within or across splits"
    env = PointMass(n_train=30)
    for walls in np.concatenate([train, test]):
        assert walls[0].all() and walls[-1].all() and walls[:, 0].all() and walls[:, -1].all()
        open_cells = (~walls).tolist()
        frac = (~walls[1:-1, 1:-1]).mean()
        assert 0.53 <= frac <= 0.88
        ys, xs = np.nonzero(~walls)
        start = (int(xs[0]), int(ys[0]))                                   # row-major first
        dist = independent_bfs(open_cells, start)
        assert len(dist) == len(xs), "not connected"
        assert max(dist.values()) < 13
        ctx = MazeContext(walls=jnp.asarray(walls))
        goal_cell = tuple(int(c) for c in np.asarray(env.eval_goals(ctx))[0] // UNIT)
        assert dist[goal_cell] == max(dist.values()), "goal is not the BFS-farthest cell"
        np.testing.assert_allclose(np.asarray(env.eval_start(ctx)), (np.array(start) + 0.5) * UNIT)


def test_behaviour_actions_are_sticky_and_bounded():
    env = PointMass()
    a = np.asarray(env.behaviour_actions(jax.random.PRNGKey(0), 5000))
    assert a.shape == (5000, 2) and np.abs(a).max() <= 1.0
    # consecutive actions mostly share a direction (new one w.p. 0.1), unlike uniform actions
    cos = (a[1:] * a[:-1]).sum(-1) / (np.linalg.norm(a[1:], axis=-1) * np.linalg.norm(a[:-1], axis=-1))
    assert np.mean(cos > 0.5) > 0.75
    ds = collect(env, jax.random.PRNGKey(1), env.contexts("train"), 2)
    assert ds.obs.shape == (60, 251, 2) and ds.action.shape == (60, 250, 2)


def test_goal_reward_within_radius(tmp_path):
    env = zsbfm.make_env("pointmass")
    ctx = jax.tree_util.tree_map(lambda x: x[0], env.contexts("test"))
    goal = env.eval_goals(ctx)[0]
    s = env.reset(jax.random.PRNGKey(0), ctx, goal=goal, start=goal + 0.5)
    s = env.step(s, jnp.zeros(2))
    assert float(s.reward) == 1.0 and bool(s.done)
    from zsbfm.envs.render import render_mazes
    path = render_mazes(tmp_path / "m.png", np.asarray(env.contexts("test").walls[:2]),
                        trajectories=[np.zeros((3, 2)) + 16, []])
    assert path.stat().st_size > 0


@pytest.mark.slow  # a learning-quality check (~20-40 s): make test-all
def test_actor_ascends_q_on_held_out_states():
    """After a short FB training, the actor's action beats random actions in Q on states
    of held-out mazes, for a fixed z (the actor is trained only through -Q)."""
    from zsbfm.agents import FBAgent, Task

    cfg = zsbfm.Config.preset("pointmass", "fb", n_train_layouts=4, episodes_per_layout=10, d=16,
                              f_pre_hidden=(64,), f_pre_out=64, f_hidden=(64,), b_hidden=(64,),
                              actor_hidden=(64, 64), batch_size=128)
    env = zsbfm.make_env("pointmass", n_train=4)
    ds = jax.jit(lambda k: collect(env, k, env.contexts("train"), 10))(jax.random.PRNGKey(0))
    agent = FBAgent(cfg, env)
    state = jax.jit(agent.init)(jax.random.PRNGKey(1))  # one compile, not one per op
    run = jit_optimised(lambda s, k: jax.lax.scan(lambda s, k: agent.update(s, ds, k), s, jax.random.split(k, 500)))
    state, metrics = run(state, jax.random.PRNGKey(2))  # 0.99 of held-out states at 500 updates
    assert np.isfinite(np.asarray(metrics["actor_q"])).all()
    held_out = jax.jit(lambda k: collect(env, k, env.contexts("test"), 1))(jax.random.PRNGKey(3))
    held_out = held_out.obs[:, ::10].reshape(-1, 2)

    @jax.jit
    def q_actor_and_random(params, held_out):
        z = agent.backward(params.B, held_out[0])
        task = Task(z=jnp.broadcast_to(z, (len(held_out), 16)), h=jnp.zeros((len(held_out), 0)))
        q = lambda a: jnp.min(jnp.einsum("knd,nd->kn", agent.forward(params.F, held_out, task, a), task.z), 0)
        q_rand = jnp.stack([q(jax.random.uniform(k, (len(held_out), 2), minval=-1, maxval=1))
                            for k in jax.random.split(jax.random.PRNGKey(4), 8)]).mean(0)
        return q(agent.act(params, held_out, task, None)), q_rand

    q_pi, q_rand = q_actor_and_random(state.params, held_out)
    assert float(jnp.mean(q_pi > q_rand)) > 0.9, float(jnp.mean(q_pi > q_rand))


@pytest.mark.slow  # ~40 s: `make test-all`
def test_continuous_rotation_fb_trains_end_to_end(tmp_path):
    """Encoder with continuous-action tokens, vMF z, actor: the whole continuous path
    (plain continuous FB is covered by the actor test above)."""
    from tests.conftest import tiny_config

    for algo in ("rfb",):
        cfg = tiny_config(tmp_path, algo, env="pointmass", eval_episode_len=30, n_train_layouts=3,
                          episodes_per_layout=6,
                          actor_hidden=(16,), enc_steps=10, enc_embed=8, enc_mlp=8,
                          pred_hidden=(8,), name=f"pm-{algo}")
        run = zsbfm.train(cfg, progress=False)
        assert len(run.results["test"]) == 2 and all(0 <= v <= 1 for v in run.results["test"])
        assert np.isfinite(run.metrics[-1]["fb_loss"]).all()


@pytest.mark.slow  # a learning-quality check (~20-40 s): make test-all
def test_actor_bc_pulls_the_policy_to_the_data_actions():
    """TD3+BC (Config.actor_bc > 0): descending the actor loss alone (F frozen at init)
    fits the dataset's actions; the pure -Q actor (actor_bc = 0) does not."""
    import dataclasses

    import optax

    from zsbfm.agents import FBAgent, Task
    from zsbfm.data.samplers import sample_transitions

    cfg = zsbfm.Config.preset("pointmass", "fb", n_train_layouts=2, episodes_per_layout=4, d=8,
                              f_pre_hidden=(32,), f_pre_out=32, f_hidden=(32,), b_hidden=(32,),
                              actor_hidden=(64, 64), batch_size=64)
    env = zsbfm.make_env("pointmass", n_train=2)
    ds = collect(env, jax.random.PRNGKey(0), env.contexts("train"), 4)
    batch = sample_transitions(jax.random.PRNGKey(1), ds, 64)
    z = jax.random.normal(jax.random.PRNGKey(2), (64, 8))
    task = Task(z=z, h=jnp.zeros((64, 0)))

    def fitted_mse(actor_bc):
        agent = FBAgent(dataclasses.replace(cfg, actor_bc=actor_bc), env)
        params = agent.init(jax.random.PRNGKey(3)).params
        opt = optax.adam(1e-3)

        def step(carry, _):
            actor, opt_state = carry
            grad = jax.grad(lambda a: agent.actor_loss(params.replace(actor=a), batch, task)[0])(actor)
            updates, opt_state = opt.update(grad, opt_state)
            return (optax.apply_updates(actor, updates), opt_state), None

        (actor, _), _ = jax.lax.scan(step, (params.actor, opt.init(params.actor)), None, 300)
        return float(jnp.mean((agent.policy(actor, batch.obs, task) - batch.action) ** 2))

    spread = float(jnp.mean(batch.action ** 2))
    mse_bc, mse_pure = fitted_mse(10.0), fitted_mse(0.0)
    assert mse_bc < 0.3 * spread and mse_bc < 0.3 * mse_pure, (mse_bc, mse_pure, spread)
    with pytest.raises(ValueError, match="actor_bc"):
        dataclasses.replace(cfg, actor_bc=-1.0)
    with pytest.raises(ValueError, match="actor_bc.*discrete"):
        zsbfm.Config.preset("fourrooms", "fb", actor_bc=0.4)


def test_cell_tokens_hold_the_map_cell_of_each_state():
    """enc_cell_tokens: the token's last n_cells entries are the one-hot of the cell
    floor(y / UNIT) * 8 + floor(x / UNIT), written out by hand; AntWind (no map) refuses it."""
    from zsbfm.agents import make_agent

    env = PointMass()
    agent = make_agent(zsbfm.Config.preset("pointmass", "bfb", enc_cell_tokens=True), env)
    pos = np.array([[0.5, 0.5], [4.0, 0.1], [31.9, 31.9], [13.0, 27.5]], np.float32)
    tok = np.asarray(agent.tokens(jnp.asarray(pos), jnp.zeros((4, 2)), jnp.asarray(pos)))
    expect = [int(y // UNIT) * 8 + int(x // UNIT) for x, y in pos]
    np.testing.assert_array_equal(tok[:, -env.n_cells:], np.eye(env.n_cells)[expect])
    with pytest.raises(ValueError, match="enc_cell_tokens"):
        zsbfm.Config.preset("antwind", "bfb", enc_cell_tokens=True)
