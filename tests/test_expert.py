"""AntWind's TD3 expert (zsbfm.data.expert): the compiled loop, the shipped expert, the caches."""

import dataclasses

import jax
import numpy as np
import pytest

import zsbfm
from zsbfm.data import expert as ex


@pytest.fixture(scope="module")
def env():
    return zsbfm.make_env("antwind")


def leaves(tree):
    """(path, shape, dtype) of every leaf: arrays or eval_shape's ShapeDtypeStructs."""
    return [(jax.tree_util.keystr(p), tuple(x.shape), np.dtype(x.dtype))
            for p, x in jax.tree_util.tree_leaves_with_path(tree)]


def test_expert_chunk_keeps_its_state_types(env):
    """The TD3 expert's chunk returns its state with the avals it was given (dtype, shape and
    weak type of every leaf), so train_expert's loop compiles the chunk once, not twice:
    a weak-typed `last_return` from init once cost a second ~30 s MJX compile. Traced with
    eval_shape (no compile)."""
    agent = ex.TD3Expert(env, ex.ExpertSettings(num_timesteps=64 * 2, chunk_iters=2, batch_size=8, hidden=(8,)))
    st = jax.eval_shape(agent.init, jax.random.PRNGKey(0))
    out = jax.eval_shape(agent.run_chunk, st)
    avals = lambda t: [(jax.tree_util.keystr(p), x.shape, x.dtype, x.weak_type)
                       for p, x in jax.tree_util.tree_leaves_with_path(t)]
    assert avals(out) == avals(st)


def test_the_preset_expert_is_shipped_and_fits_the_actor(env):
    """The AntWind preset's expert settings (seed 0) have a shipped expert: changing
    ExpertSettings or the env's constants changes its key, and this fails until the expert
    is trained and shipped anew. Its leaves are the actor's, shape for shape."""
    settings = ex.expert_settings(zsbfm.Config.preset("antwind"))
    path = ex.shipped_expert_path(env, settings)
    assert path is not None, f"no shipped expert antwind-expert-{ex.expert_key(env, settings)}.npz"
    agent = ex.TD3Expert(env, settings)
    actor = jax.eval_shape(agent.actor_net.init, jax.random.PRNGKey(0), np.zeros((1, env.obs_dim + 2)))
    assert leaves(ex.load_expert_npz(path)) == leaves(actor)
    assert ex.shipped_expert_path(env, dataclasses.replace(settings, seed=1)) is None


def test_expert_sources_and_caches(env, tmp_path, monkeypatch):
    """source="shipped" reads the shipped expert and trains nothing; source="train" trains
    once, caches the actor as .npz (read back exactly), and reads the cache the next time.
    The datasets of the two origins have different cache files."""
    settings = ex.expert_settings(zsbfm.Config.preset("antwind"))
    calls = []
    params = {"params": {"Dense_0": {"kernel": np.arange(6, dtype=np.float32).reshape(2, 3),
                                     "bias": np.ones(3, np.float32)}}}

    def fake_train(env, settings, progress):
        calls.append(settings)
        return params

    monkeypatch.setattr(ex, "train_expert", fake_train)
    shipped = ex.load_or_train_expert(env, settings, str(tmp_path), progress=False)
    assert calls == [] and not (tmp_path / "antwind").exists()
    assert leaves(shipped) == leaves(ex.load_expert_npz(ex.shipped_expert_path(env, settings)))

    ex.load_or_train_expert(env, settings, str(tmp_path), progress=False, source="train")
    again = ex.load_or_train_expert(env, settings, str(tmp_path), progress=False, source="train")
    assert len(calls) == 1                                          # the second read the cache
    jax.tree_util.tree_map(np.testing.assert_array_equal, again, params)
    assert [p.name for p in (tmp_path / "antwind").iterdir()] == [f"expert-{ex.expert_key(env, settings)}.npz"]

    cfg = zsbfm.Config.preset("antwind", data_dir=str(tmp_path))
    assert ex.dataset_path(cfg, env) != ex.dataset_path(cfg.replace(expert_source="train"), env)
    assert ex.dataset_path(cfg, env) == ex.dataset_path(cfg.replace(name="other"), env)
