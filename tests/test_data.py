"""Collection keeps episodes apart; samplers draw from the right episode and law."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import zsbfm
from zsbfm.data import (collect, geometric_offsets, load_dataset, sample_future, sample_states,
                        sample_transitions, sample_windows, save_dataset)
from zsbfm.envs import index_contexts


@pytest.fixture(scope="module")
def env_ds():
    env = zsbfm.make_env("fourrooms", n_train=5)
    ds = jax.jit(lambda k: collect(env, k, env.contexts("train"), 40))(jax.random.PRNGKey(0))
    return env, ds


def test_shapes_and_context_ids(env_ds):
    env, ds = env_ds
    assert ds.obs.shape == (200, 101, 2) and ds.action.shape == (200, 100)
    assert ds.num_transitions == 20_000
    np.testing.assert_array_equal(np.asarray(ds.context_id), np.repeat(np.arange(5), 40))


def test_every_transition_follows_its_episodes_layout(env_ds):
    """Replaying each stored action through env.step in the episode's own layout
    reproduces the stored next state: no transition crosses episodes or layouts."""
    env, ds = env_ds
    ctxs = env.contexts("train")

    def replay(obs, action, cid):
        ctx = index_contexts(ctxs, cid)
        state = env.reset(jax.random.PRNGKey(0), ctx, start=obs[0].astype(jnp.int32))

        def step(s, a):
            s = env.step(s, a)
            return s, s.obs

        _, out = jax.lax.scan(step, state, action)
        return out

    replayed = jax.jit(jax.vmap(replay))(ds.obs, ds.action, ds.context_id)
    np.testing.assert_array_equal(np.asarray(replayed), np.asarray(ds.obs[:, 1:]))


def test_episodes_differ_and_seeds_differ(env_ds):
    env, ds = env_ds
    assert len({np.asarray(ds.obs[i]).tobytes() for i in range(ds.num_episodes)}) == ds.num_episodes
    ds2 = collect(env, jax.random.PRNGKey(1), env.contexts("train"), 40)
    assert not np.array_equal(np.asarray(ds.obs), np.asarray(ds2.obs))


def test_transitions_sampler_is_consistent(env_ds):
    _, ds = env_ds
    b = sample_transitions(jax.random.PRNGKey(2), ds, 512)
    np.testing.assert_array_equal(np.asarray(b.obs), np.asarray(ds.obs[b.episode, b.t]))
    np.testing.assert_array_equal(np.asarray(b.next_obs), np.asarray(ds.obs[b.episode, b.t + 1]))
    np.testing.assert_array_equal(np.asarray(b.action), np.asarray(ds.action[b.episode, b.t]))
    assert int(b.t.max()) < 100 and int(b.t.min()) >= 0


def test_geometric_offsets_follow_the_law():
    gamma = 0.8
    k = np.asarray(geometric_offsets(jax.random.PRNGKey(3), (200_000,), gamma))
    assert k.min() == 1
    for j in range(1, 8):
        expected = (1 - gamma) * gamma ** (j - 1)
        emp = np.mean(k == j)
        # binomial standard error at n=200k is < 1e-3; 5 sigma
        assert abs(emp - expected) < 5 * np.sqrt(expected * (1 - expected) / k.size), (j, emp, expected)
    assert abs(k.mean() - 1 / (1 - gamma)) < 0.02


def test_future_states_come_from_the_same_episode(env_ds):
    """Uses an episode whose states are all distinct tags so the offset is recoverable."""
    _, ds = env_ds
    E, T = 64, 100
    tagged = ds.replace(obs=jnp.broadcast_to(jnp.arange(E)[:, None, None] * 1000.0
                                             + jnp.arange(T + 1)[None, :, None], (E, T + 1, 2)),
                        action=ds.action[:E], context_id=ds.context_id[:E])
    ep = jax.random.randint(jax.random.PRNGKey(4), (50_000,), 0, E)
    t = jnp.full((50_000,), 10)
    fut = np.asarray(sample_future(jax.random.PRNGKey(5), tagged, ep, t, 0.9))[:, 0]
    assert np.array_equal(fut // 1000, np.asarray(ep)), "future state from another episode"
    offset = fut % 1000 - 10
    assert offset.min() >= 1 and offset.max() <= T - 10
    for j in (1, 2, 5):
        expected = 0.1 * 0.9 ** (j - 1)
        assert abs(np.mean(offset == j) - expected) < 5 * np.sqrt(expected / offset.size)
    # truncation at the episode end: P(offset = 90) = P(k >= 90) = 0.9^89
    assert abs(np.mean(offset == T - 10) - 0.9 ** 89) < 1e-3


def test_windows_are_contiguous_and_from_one_episode(env_ds):
    _, ds = env_ds
    ep = jnp.arange(8)
    obs, action, nobs = sample_windows(jax.random.PRNGKey(6), ds, ep, 25)
    assert obs.shape == (8, 25, 2) and action.shape == (8, 25)
    for i in range(8):
        full = np.asarray(ds.obs[i])
        # locate the window start
        starts = [s for s in range(0, 76) if np.array_equal(full[s:s + 25], np.asarray(obs[i]))]
        assert starts
        s = starts[0]
        np.testing.assert_array_equal(np.asarray(nobs[i]), full[s + 1:s + 26])
        np.testing.assert_array_equal(np.asarray(action[i]), np.asarray(ds.action[i, s:s + 25]))
    with pytest.raises(ValueError, match="longer than an episode"):
        sample_windows(jax.random.PRNGKey(6), ds, ep, 101)


def test_sample_states_excludes_nothing_but_initial(env_ds):
    _, ds = env_ds
    s = sample_states(jax.random.PRNGKey(7), ds, 1000)
    assert s.shape == (1000, 2)


def test_save_load_roundtrip(env_ds, tmp_path):
    _, ds = env_ds
    path = save_dataset(str(tmp_path / "d.npz"), ds)
    with np.load(path) as f:
        assert set(f.files) == {"obs", "action", "context_id"}
    back = load_dataset(path)
    for a, b in zip(jax.tree_util.tree_leaves(ds), jax.tree_util.tree_leaves(back)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    np.savez(str(tmp_path / "bad.npz"), obs=np.zeros(3))
    with pytest.raises(ValueError, match="missing arrays"):
        load_dataset(str(tmp_path / "bad.npz"))
