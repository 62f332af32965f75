"""AntWind on MJX: agreement with native MuJoCo, the wind's effect, splits, rewards.

MJX compiles an Ant rollout in tens of seconds on this CPU, so every test here shares one
compiled function (`rollouts`, module scope) of fixed shapes.
"""

import dataclasses

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from zsbfm.config import Config
from zsbfm.envs import make_env
from zsbfm.envs.antwind import (FRAME_SKIP, N_WINDS, TORSO, WIND_FORCE, WindContext, mj_model,
                                state_reward, wind_angles, wind_context)

T = 100         # env steps per rollout (5 s of simulated time)
K = 8           # action sequences per wind: K // 2 random, K // 2 standing still (zero actions)
ANGLES = (0.0, np.pi / 2, np.pi)


@pytest.fixture(scope="module")
def env():
    return make_env("antwind")


@pytest.fixture(scope="module")
def rollouts(env):
    """K = 8 action sequences (4 uniformly random, 4 zero) and random starts, each rolled
    out under the winds 0, pi/2, pi and no wind. Returns (start qpos [K, 15], start qvel [K, 14], qpos [4, K, T, 15],
    obs [4, K, T, 27], reward [4, K, T], actions [K, T, 8], contexts)."""
    ctx = wind_context(jnp.asarray(ANGLES))
    ctx = WindContext(angle=jnp.append(ctx.angle, 0.0), force=jnp.concatenate([ctx.force, jnp.zeros((1, 3))]))
    actions = jax.random.uniform(jax.random.PRNGKey(1), (K, T, 8), minval=-1, maxval=1)
    actions = actions.at[K // 2:].set(0.0)
    keys = jax.random.split(jax.random.PRNGKey(0), K)

    def roll(c, key, actions):
        s = env.reset(key, c)

        def body(s, a):
            s = env.step(s, a)
            return s, (s.inner.qpos, s.obs, s.reward)

        return s.inner.qpos, s.inner.qvel, jax.lax.scan(body, s, actions)[1]

    per_wind = jax.vmap(roll, in_axes=(None, 0, 0))
    q0, v0, (q, obs, r) = jax.jit(jax.vmap(per_wind, in_axes=(0, None, None)))(ctx, keys, actions)
    return np.asarray(q0[0]), np.asarray(v0[0]), np.asarray(q), np.asarray(obs), np.asarray(r), np.asarray(actions), ctx


def test_mjx_matches_native_mujoco(rollouts):
    """The same start, actions and wind (0 rad) in native MuJoCo (C, float64) and in the
    MJX env: identical to float precision for 3 env steps (15 physics steps), the torso
    within 10 cm over 10 (see experiments/antwind_native.py for a trained policy's return)."""
    q0, v0, q, _, _, actions, ctx = rollouts
    m = mj_model()
    d = mujoco.MjData(m)
    d.qpos[:], d.qvel[:] = q0[0], v0[0]
    mujoco.mj_forward(m, d)
    err, torso_err = [], []
    for t in range(10):
        d.ctrl[:] = actions[0, t]
        d.xfrc_applied[TORSO, :3] = np.asarray(ctx.force[0])
        for _ in range(FRAME_SKIP):
            mujoco.mj_step(m, d)
        err.append(np.abs(q[0, 0, t] - d.qpos).max())
        torso_err.append(np.abs(q[0, 0, t, :3] - d.qpos[:3]).max())
    # float32 MJX and float64 MuJoCo agree to ~1e-6 until a foot contact makes or breaks
    # differently (step 5 here); from then on the chaotic contact dynamics drift apart
    # (joint angles by ~0.1 rad after 10 steps) while the torso stays within centimetres
    # (measured: 1-6 cm after 10 steps).
    assert max(err[:3]) < 1e-5, err
    assert max(torso_err) < 0.1, torso_err
    assert np.abs(d.qpos - q0[0]).max() > 0.1  # the ant did move (joints swing by tenths of a radian)


def test_wind_pushes_the_ant_downwind(rollouts):
    """An ant standing still (zero actions) drifts along the wind: its displacement relative
    to the no-wind rollout, averaged over the K // 2 still starts, points along the wind.
    (Under random actions the walk is chaotic, metres per 5 s either way, and a mean over a
    few sequences does not resolve the wind's ~0.25 m.)"""
    _, _, q, _, _, _, _ = rollouts
    disp = (q[:, K // 2:, -1, :2] - q[:, K // 2:, 0, :2]).mean(1)  # [4, 2]
    base = disp[3]
    for i, angle in enumerate(ANGLES):
        shift = disp[i] - base
        direction = np.array([np.cos(angle), np.sin(angle)])
        assert shift @ direction / np.linalg.norm(shift) > 0.8, (angle, shift)
        assert np.linalg.norm(shift) > 0.1, (angle, shift)


def test_never_below_the_floor_and_rewards_consistent(rollouts):
    _, _, q, obs, r, actions, _ = rollouts
    assert np.all(np.isfinite(q)) and q[..., 2].min() > 0.15  # the torso (radius 0.25) rests on the floor at worst
    np.testing.assert_allclose(obs[..., 0], q[..., 2], rtol=1e-6)  # obs[0] is the torso height
    # step reward = forward displacement / dt + healthy - ctrl cost; state_reward uses qvel_x instead
    ctrl = 0.5 * np.sum(actions ** 2, -1)  # [K, T]
    dt = mj_model().opt.timestep * FRAME_SKIP
    healthy = ((q[..., 2] > 0.3) & (q[..., 2] < 1.0)).astype(float)
    x_prev = np.concatenate([np.zeros((4, K, 1)), q[:, :, :-1, 0]], 2)  # reset starts at x = 0
    np.testing.assert_allclose(r, (q[..., 0] - x_prev) / dt + healthy - ctrl[None], atol=1e-3)
    s = np.asarray(state_reward(jnp.asarray(obs)))
    np.testing.assert_allclose(s - healthy, obs[..., 13], atol=1e-6)  # qvel_x + healthy
    # qvel_x at the step's end tracks the step's mean forward speed
    assert np.corrcoef(s.ravel(), (r + ctrl[None]).ravel())[0, 1] > 0.5


def test_wind_splits():
    train, test = wind_angles("train"), wind_angles("test")
    assert len(train) == 15 and len(test) == 5 and len(train) + len(test) == N_WINDS
    assert set(np.round(train, 6)).isdisjoint(np.round(test, 6))
    assert train.max() < 1.5 * np.pi <= test.min()
    np.testing.assert_allclose(np.diff(np.sort(np.concatenate([train, test]))), 2 * np.pi / N_WINDS, rtol=1e-9)
    ctx = make_env("antwind").contexts("test")
    np.testing.assert_allclose(np.linalg.norm(np.asarray(ctx.force), axis=-1), WIND_FORCE, rtol=1e-6)
    feats = np.asarray(jax.vmap(make_env("antwind").context_features)(ctx))  # the oracle's "walls" h
    np.testing.assert_allclose(feats, WIND_FORCE * np.stack([np.cos(test), np.sin(test)], -1), atol=1e-5)
    with pytest.raises(ValueError, match="split"):
        make_env("antwind").contexts("valid")


def test_antwind_config_errors():
    with pytest.raises(ValueError, match="n_train_layouts=20.*15 for antwind"):
        Config.preset("antwind", n_train_layouts=20)
    with pytest.raises(ValueError, match="data_policy='sac'"):
        Config.preset("antwind", data_policy="sac")
    with pytest.raises(ValueError, match="expert_source='download'.*'shipped', 'train'"):
        Config.preset("antwind", expert_source="download")
    with pytest.raises(ValueError, match="obs_encoding"):
        Config.preset("antwind", obs_encoding="onehot")
    cfg = Config.preset("antwind")
    assert cfg.episode_len == 256 and cfg.eval_episode_len == 256 and cfg.obs_encoding == "raw"
    assert dataclasses.replace(cfg, size="paper").size == "paper"


@pytest.mark.slow
def test_antwind_rfb_end_to_end(tmp_path):
    """A tiny expert (random warm-up only), a tiny dataset (cached, then read back) and a
    tiny Rotation-FB run through zsbfm.train: returns per seed, finite and different."""
    import zsbfm
    from zsbfm.data.expert import load_or_collect_dataset
    from zsbfm.data.sources import make_env_for

    cfg = Config.preset("antwind", "rfb", num_seeds=2, expert_steps=512, episodes_per_layout=2,
                        data_dir=str(tmp_path / "data"), runs_dir=str(tmp_path / "runs"), d=8,
                        f_pre_hidden=(16,), f_pre_out=16, f_hidden=(32,), b_hidden=(16,), actor_hidden=(16,),
                        batch_size=32, steps=20, chunk_steps=10, enc_steps=10, enc_embed=8, enc_heads=2,
                        enc_mlp=8, enc_batch=2, pred_hidden=(8,), eval_episode_len=16, context_len=16)
    run = zsbfm.train(cfg, progress=False)
    assert run.results["metric"] == "return"
    train, test = np.asarray(run.results["train"]), np.asarray(run.results["test"])
    assert train.shape == test.shape == (2,) and np.all(np.isfinite(train)) and np.all(np.isfinite(test))
    assert train[0] != train[1]  # vmapped seeds are different runs
    cached = sorted(p.name.split("-")[0] for p in (tmp_path / "data" / "antwind").iterdir())
    assert cached == ["data", "expert"]  # the dataset and the expert (trained here: no shipped one), cached
    ds = load_or_collect_dataset(cfg, make_env_for(cfg, progress=False), progress=False)  # read back
    assert ds.obs.shape == (15 * 2, 257, 27) and ds.action.shape == (15 * 2, 256, 8)

