"""How much of the dynamics context the encoder recovers, for encoder settings given as --set.

    python experiments/fb_diagnostics/encoder_probe.py [--env antwind] [--set enc_contrast=1 ...]

Trains only f_dyn (the staged pre-training phase, `BeliefFBAgent.pretrain_step`) on the
preset's dataset (AntWind: the cached one; gridworlds and pointmass: collected here), then
probes mu of one context window per episode, fitting on 80% of each layout's episodes and
scoring the other 20%:
- AntWind: ridge regression of (cos, sin) of the wind angle on mu; the angle error in
  degrees (90 = chance), also on whole held-out train winds (fit on the even winds, score
  the odd ones: does h interpolate between winds?), and on fresh episodes of the 5 test
  winds with the probe fitted on all train winds (does h extrapolate to the unseen quadrant?).
- other envs: nearest-centroid accuracy of the layout (chance = 1 / layouts); and for the
  gridworlds, a ridge probe of the layout's interior wall map (env.context_features) on mu,
  fitted on every train episode and scored on fresh episodes of the 20 held-out test layouts
  (does h describe walls it has never seen?): the fraction of interior cells classified
  right, and the balanced accuracy (mean of wall and free recall) on the cells that are
  walls in some layouts and free in others, beside the mean train map's; with
  --set h_from=context also the encoder's own predicted wall map c(mu), the h F reads.
  --json appends one line of these figures.
Also prints the predictor's MSE with each episode's own h and with h of a random other
episode (the gap is what h buys the predictor).
"""
from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np

from zsbfm.agents import make_agent
from zsbfm.config import Config
from zsbfm.data.collect import collect
from zsbfm.data.expert import load_or_collect_dataset
from zsbfm.data.sources import make_env_for
from zsbfm.data.samplers import sample_windows


def probe_error(mu, ang, fit, score):
    """Angle error (degrees) of a ridge probe (cos, sin) <- [mu, 1], fitted on `fit`, on `score`."""
    X = np.concatenate([mu, np.ones((len(mu), 1))], 1)
    Y = np.stack([np.cos(ang), np.sin(ang)], 1)
    A = X[fit].T @ X[fit] + 1e-3 * np.eye(X.shape[1])
    W = np.linalg.solve(A, X[fit].T @ Y[fit])
    P = X[score] @ W
    err = np.angle(np.exp(1j * (np.arctan2(P[:, 1], P[:, 0]) - ang[score])))
    return float(np.degrees(np.abs(err)).mean())


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--env", default="antwind", choices=["antwind", "pointmass", "fourrooms", "doors"])
    p.add_argument("--set", nargs="*", default=[])
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", default="", help="append the figures as one JSON line to this file")
    a = p.parse_args()
    out = {"env": a.env, "set": a.set, "seed": a.seed}
    cfg = Config.preset(a.env, "bfb", "cpu", num_seeds=1).with_overrides(a.set)
    env = make_env_for(cfg, progress=False)
    agent = make_agent(cfg, env)
    if a.env == "antwind":
        ds = load_or_collect_dataset(cfg, env, progress=False)
    else:
        ds = jax.jit(lambda k: collect(env, k, env.contexts("train"), cfg.episodes_per_layout))(
            jax.random.PRNGKey(a.seed + 100))
    state = agent.init(jax.random.PRNGKey(a.seed))
    K = cfg.enc_steps

    @jax.jit
    def pretrain(state, key):
        return jax.lax.scan(lambda s, k: agent.pretrain_step(s, ds, k), state, jax.random.split(key, K))

    t = time.time()
    state, m = pretrain(state, jax.random.PRNGKey(a.seed + 1))
    mse = np.asarray(m["enc_mse"])
    print(f"pre-training {K} steps: {time.time() - t:.0f}s; enc_mse first/last 200 steps "
          f"{mse[:200].mean():.4f} / {mse[-200:].mean():.4f}")

    enc = state.params.enc
    n_ep = ds.num_episodes
    ep = jnp.arange(n_ep)
    encode_mu = jax.jit(lambda o, a_, n: agent.encode(enc, o, a_, n)[0])
    mu = np.asarray(encode_mu(*sample_windows(jax.random.PRNGKey(5), ds, ep, cfg.context_len)))
    layout = np.asarray(ds.context_id)
    per = cfg.episodes_per_layout
    within = np.arange(n_ep) % per
    fit, score = within < int(0.8 * per), within >= int(0.8 * per)
    if a.env == "antwind":
        ang = np.asarray(env.contexts("train").angle)[layout]
        even = layout % 2 == 0
        print(f"wind probe angle error (deg, 90 = chance): held-out episodes {probe_error(mu, ang, fit, score):.1f}; "
              f"held-out winds (fit even, score odd) {probe_error(mu, ang, even, ~even):.1f}")
        # the unseen quadrant: fresh behaviour episodes under the 5 test winds, the probe fitted
        # on every train episode (are never-seen winds "in place" on the train winds' circle?)
        tds = jax.jit(lambda k: collect(env, k, env.contexts("test"), 8))(jax.random.PRNGKey(a.seed + 200))
        mu_t = np.asarray(encode_mu(*sample_windows(jax.random.PRNGKey(7), tds, jnp.arange(tds.num_episodes),
                                                    cfg.context_len)))
        ang_t = np.asarray(env.contexts("test").angle)[np.asarray(tds.context_id)]
        both = np.concatenate([mu, mu_t]), np.concatenate([ang, ang_t])
        is_test = np.arange(len(both[0])) >= len(mu)
        print(f"test winds (unseen quadrant, probe fitted on all train episodes): angle error "
              f"{probe_error(*both, ~is_test, is_test):.1f} deg")
    else:
        cents = np.stack([mu[fit & (layout == i)].mean(0) for i in range(cfg.n_train_layouts)])
        guess = np.linalg.norm(mu[score][:, None] - cents[None], axis=-1).argmin(1)
        out["centroid_accuracy"] = float(np.mean(guess == layout[score]))
        print(f"layout nearest-centroid accuracy on held-out episodes: {out['centroid_accuracy']:.3f} "
              f"(chance {1 / cfg.n_train_layouts:.3f})")
        if hasattr(env, "context_features"):
            out.update(wall_probe(env, agent, enc, cfg, mu, layout, a.seed))

    # what h buys the predictor: own h vs a random other episode's h (same targets)
    target = sample_windows(jax.random.PRNGKey(6), ds, ep, cfg.context_len)
    perm = np.random.default_rng(0).permutation(n_ep)
    pred_mse = jax.jit(lambda h: agent.predictor_mse(enc, h, *target))
    own, other = float(pred_mse(jnp.asarray(mu))), float(pred_mse(jnp.asarray(mu[perm])))
    print(f"predictor mse: own h {own:.4f}, another episode's h {other:.4f} (gap {other - own:.4f}); "
          f"mu spread: mean |mu - mean| {np.linalg.norm(mu - mu.mean(0), axis=1).mean():.3f}")
    out.update(pred_mse_own=own, pred_mse_other=other)
    if a.json:
        import json

        with open(a.json, "a") as f:
            f.write(json.dumps(out) + "\n")


def wall_probe(env, agent, enc, cfg, mu, layout, seed, test_episodes=20) -> dict:
    """Ridge probe wall map <- [mu, 1] fitted on the train episodes, scored on fresh episodes
    of the held-out test layouts: accuracy over all interior cells and over the door cells
    (cells free in some train layout and walled in another: where layouts differ)."""
    feats = lambda ctx: np.asarray(jax.vmap(env.context_features)(ctx))
    train_w, test_w = feats(env.contexts("train")), feats(env.contexts("test"))
    tds = jax.jit(lambda k: collect(env, k, env.contexts("test"), test_episodes))(jax.random.PRNGKey(seed + 300))
    mu_t = np.asarray(jax.jit(lambda o, a_, n: agent.encode(enc, o, a_, n)[0])(
        *sample_windows(jax.random.PRNGKey(8), tds, jnp.arange(tds.num_episodes), cfg.context_len)))
    X = np.concatenate([mu, np.ones((len(mu), 1))], 1)
    W = np.linalg.solve(X.T @ X + 1e-2 * np.eye(X.shape[1]), X.T @ train_w[layout])
    pred = np.concatenate([mu_t, np.ones((len(mu_t), 1))], 1) @ W > 0.5
    truth = test_w[np.asarray(tds.context_id)] > 0.5
    # cells walled in some layouts and free in others (train or test): where layouts differ
    both = np.concatenate([train_w, test_w])
    varies = (both.min(0) < 0.5) & (both.max(0) > 0.5)

    def balanced(guess):  # the mean of wall recall and free-cell recall over the varying cells
        g, t = guess[:, varies], truth[:, varies]
        return float(0.5 * (np.mean(g[t]) + np.mean(~g[~t])))

    mean_map = np.broadcast_to(train_w.mean(0) > 0.5, truth.shape)
    res = {"test_wall_cell_accuracy": float(np.mean(pred == truth)),
           "test_varying_cell_balanced_accuracy": balanced(pred),
           "mean_map_varying_cell_balanced_accuracy": balanced(mean_map)}
    print(f"wall-map probe on unseen test layouts: all cells {res['test_wall_cell_accuracy']:.3f}; balanced "
          f"accuracy on the cells that differ between layouts {res['test_varying_cell_balanced_accuracy']:.3f} "
          f"(the mean train map: {res['mean_map_varying_cell_balanced_accuracy']:.3f}, 0.5 = chance)")
    if cfg.h_from == "context":  # the h F reads: the encoder's own head c(mu), no probe fitted
        h_t = np.asarray(agent.context_head.apply(enc["context_head"], jnp.asarray(mu_t)))
        truth_f = test_w[np.asarray(tds.context_id)]
        res.update(head_varying_cell_balanced_accuracy=balanced(h_t > 0.5),
                   head_test_mse=float(np.mean((h_t - truth_f) ** 2)),
                   mean_map_test_mse=float(np.mean((train_w.mean(0) - truth_f) ** 2)))
        print(f"h = c(mu) on unseen test layouts: balanced accuracy {res['head_varying_cell_balanced_accuracy']:.3f}; "
              f"MSE to the wall map {res['head_test_mse']:.4f} (the mean train map: {res['mean_map_test_mse']:.4f})")
    return res


if __name__ == "__main__":
    main()
