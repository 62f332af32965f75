"""How much one AntWind step reveals the wind, for several wind strengths.

    python experiments/fb_diagnostics/antwind_wind_signal.py [--forces 2 6] [--episodes 6]

Rolls out uniform random actions under all 20 wind directions at each force (newtons on
the torso; the env uses antwind.WIND_FORCE), then fits the torso's velocity change
s'[13:15] - s[13:15] by least squares on (s, a), with and without the wind's unit vector
(cos, sin) as extra inputs. Prints the share of the residual variance the wind explains
(what a predictor g(s, a, h) could gain from a perfect h), the fraction of healthy steps,
and how many episodes became non-finite (the MJX solver's limit under strong winds).
"""
from __future__ import annotations

import argparse

import jax
import jax.numpy as jnp
import numpy as np

from zsbfm.data.collect import collect
from zsbfm.envs import make_env
from zsbfm.envs.antwind import N_WINDS, WindContext


def lstsq_residual(X: np.ndarray, y: np.ndarray) -> np.ndarray:
    X = np.concatenate([X, np.ones((len(X), 1))], 1)
    W = np.linalg.lstsq(X, y, rcond=None)[0]
    return ((y - X @ W) ** 2).mean(0)


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--forces", type=float, nargs="+", default=[2.0, 6.0])
    p.add_argument("--episodes", type=int, default=6, help="episodes per wind")
    a = p.parse_args()
    env = make_env("antwind")
    ang = 2 * np.pi * np.arange(N_WINDS) / N_WINDS
    unit = np.stack([np.cos(ang), np.sin(ang), 0 * ang], -1)
    for F in a.forces:
        ctx = WindContext(angle=jnp.asarray(ang, jnp.float32), force=jnp.asarray(F * unit, jnp.float32))
        ds = jax.jit(lambda k: collect(env, k, ctx, a.episodes))(jax.random.PRNGKey(0))
        obs, act, cid = np.asarray(ds.obs), np.asarray(ds.action), np.asarray(ds.context_id)
        finite = np.isfinite(obs).all((1, 2))
        obs, act, cid = obs[finite], act[finite], cid[finite]
        T = act.shape[1]
        s, s2 = obs[:, :-1].reshape(-1, obs.shape[-1]), obs[:, 1:].reshape(-1, obs.shape[-1])
        sa = np.concatenate([s, act.reshape(len(s), -1)], 1)
        wind = np.repeat(unit[cid, :2], T, 0)
        y = s2[:, 13:15] - s[:, 13:15]
        r0, r1 = lstsq_residual(sa, y), lstsq_residual(np.concatenate([sa, wind], 1), y)
        z = obs[:, :, 0]
        print(f"wind {F:g} N: torso velocity change var {y.var(0).round(4)}, residual on (s, a) {r0.round(4)}, "
              f"+ wind {r1.round(4)}: wind explains {(100 * (r0 - r1) / r0).round(2)}% (x, y); "
              f"healthy steps {np.mean((z > 0.3) & (z < 1.0)):.2f}; non-finite episodes {int((~finite).sum())} "
              f"of {len(finite)}", flush=True)


if __name__ == "__main__":
    main()
