"""PCA of the inferred context h over AntWind's winds (paper Figure 9, right).

    python experiments/antwind_h_pca.py --run runs/antwind-bfb-cpu [--episodes 4]

For each of the 20 wind directions (15 train, 5 held out), `--episodes` reward-free
expert episodes of context_len steps are encoded to h = mu(episode) by the run's seed-0
encoder; the 2-D PCA (fitted on the train winds) is drawn coloured by wind angle on a
cyclic colour map, held-out winds as squares. Also prints how well h orders the winds: the
circular correlation between the wind angle and the angle of h in the PCA plane, and the
nearest-train-wind error (degrees) of each held-out episode's h, beside its floor (the error
of a perfect encoder: each held-out wind's closest train wind).
Writes results/figures/antwind_h_pca.png and .json.
"""

from __future__ import annotations

import argparse
import json
import os

import jax
import jax.numpy as jnp
import numpy as np

from zsbfm.agents import make_agent
from zsbfm.data.collect import collect
from zsbfm.data.sources import make_env_for
from zsbfm.envs.antwind import wind_context
from zsbfm.run import load


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--run", default="runs/antwind-bfb-cpu")
    p.add_argument("--episodes", type=int, default=4)
    p.add_argument("--out", default="results/figures")
    a = p.parse_args()
    run = load(a.run)
    cfg = run.cfg
    if cfg.algo not in ("bfb", "rfb"):
        raise SystemExit(f"--run {a.run} is {cfg.algo!r}; h exists for bfb and rfb runs")
    env = make_env_for(cfg)
    agent = make_agent(cfg, env)
    params = run.seed_params(0)
    angles = {s: np.asarray(env.contexts(s).angle) for s in ("train", "test")}
    all_angles = np.concatenate([angles["train"], angles["test"]])
    ds = jax.jit(lambda k: collect(env, k, wind_context(jnp.asarray(all_angles)), a.episodes))(jax.random.PRNGKey(7))
    obs, act = ds.obs[:, :cfg.context_len + 1], ds.action[:, :cfg.context_len]
    mu, _ = agent.encode(params.enc, obs[:, :-1], act, obs[:, 1:])
    h = np.asarray(mu)
    ang = all_angles[np.asarray(ds.context_id)]
    is_test = np.asarray(ds.context_id) >= len(angles["train"])

    mean = h[~is_test].mean(0)
    _, _, vt = np.linalg.svd(h[~is_test] - mean, full_matrices=False)
    xy = (h - mean) @ vt[:2].T
    phi = np.arctan2(xy[:, 1], xy[:, 0])
    # circular correlation of wind angle and PCA angle (sign-free: PCA axes may be mirrored)
    c = [abs(np.mean(np.exp(1j * (phi - s * ang)))) for s in (1, -1)]
    # nearest train-wind centroid of each held-out episode's h
    cents = np.stack([h[(~is_test) & (ang == t)].mean(0) for t in angles["train"]])
    nearest = angles["train"][np.argmin(np.linalg.norm(h[is_test][:, None] - cents[None], axis=-1), 1)]
    def ang_dist(x, y):  # degrees between angles (radians), in [0, 180]
        return np.degrees(np.abs((x - y + np.pi) % (2 * np.pi) - np.pi))

    err = ang_dist(nearest, ang[is_test])
    # the least this error can be: a held-out wind's closest train wind (a perfect encoder)
    floor = ang_dist(angles["train"][None], ang[is_test][:, None]).min(1)
    stats = {"run": a.run, "angle_coherence": float(max(c)), "test_nearest_train_wind_error_deg": float(err.mean()),
             "test_error_floor_deg": float(floor.mean()), "wind_spacing_deg": 18.0}

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(4.6, 4.0))
    sc = ax.scatter(xy[~is_test, 0], xy[~is_test, 1], c=np.degrees(ang[~is_test]), cmap="hsv", vmin=0, vmax=360,
                    s=18, label="train winds")
    ax.scatter(xy[is_test, 0], xy[is_test, 1], c=np.degrees(ang[is_test]), cmap="hsv", vmin=0, vmax=360,
               s=40, marker="s", edgecolors="k", label="held-out winds")
    fig.colorbar(sc, ax=ax, label="wind angle (deg)")
    ax.set_title(f"h of AntWind episodes ({cfg.algo}, seed 0)", fontsize=9)
    ax.set_xlabel("PC 1")
    ax.set_ylabel("PC 2")
    ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    os.makedirs(a.out, exist_ok=True)
    fig.savefig(os.path.join(a.out, "antwind_h_pca.png"), dpi=120)
    with open(os.path.join(a.out, "antwind_h_pca.json"), "w") as f:
        json.dump(stats, f, indent=2)
    print(json.dumps(stats))


if __name__ == "__main__":
    main()
