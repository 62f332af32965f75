"""Can a nonlinear head read the wall map out of a Belief-FB run's frozen encoder?

    python experiments/fb_diagnostics/map_probe.py runs/<run> [--contexts 32] [--steps 3000]
        [--seeds 0 1 2] [--json results/fourrooms_map_probe.jsonl]

For a run with h_from="context" (its F reads a wall map): draws --contexts fresh test-time
contexts (the run's context_episodes x context_len) of every train and held-out layout,
encodes them with the run's frozen encoder (seed 0), and fits an MLP (512, 512, sigmoid
outputs, binary cross-entropy, Adam 1e-3, batch 256) from mu to the layout's interior wall
map on the *train* layouts' contexts only. Reports the rounded map's error on the cells that
differ between layouts (train / held-out) for the run's own head c(mu) (the json's
"linear_head_map_error", named when c was always linear) and for the
probe, and the paper-protocol success of the run's F given the probe's rounded map (the
run's own evaluation keys, `zsbfm.evaluate(agent=...)`). A probe, not a method: it shows
whether the encoder's mu holds the map and the linear head is what loses it. Each --seeds
entry draws its own contexts and probe initialisation (the F and encoder are the run's).
"""
from __future__ import annotations

import argparse
import json

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax

import zsbfm
from zsbfm.agents import make_agent
from zsbfm.data.sources import make_env_for
from zsbfm.evaluate import context_episode, protocol_score

from context_coverage import varying_cells  # this script's folder is on sys.path
from h_swap import per_layout, with_context_h


class ProbeMLP(nn.Module):
    @nn.compact
    def __call__(self, x):
        for width in (512, 512):
            x = nn.relu(nn.Dense(width)(x))
        return nn.Dense(self.n_out)(x)

    n_out: int = 81


def encode_contexts(agent, params, env, split: str, n: int, key):
    """mu [layouts * n, mu_dim] of n fresh contexts per layout, and each one's true map."""
    cfg = agent.cfg
    one = lambda k, lay: agent.context_mu(params, context_episode(env, k, lay, cfg.context_len,
                                                                    cfg.context_episodes))
    mu = np.asarray(per_layout(env, split, n, key, one))                 # [n_layouts, n, mu_dim]
    maps = np.repeat(np.asarray(jax.vmap(env.context_features)(env.contexts(split))), n, 0)
    return mu.reshape(-1, mu.shape[-1]), maps


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("run")
    p.add_argument("--contexts", type=int, default=32, help="fresh contexts per layout")
    p.add_argument("--steps", type=int, default=3000, help="probe training steps")
    p.add_argument("--seeds", type=int, nargs="+", default=[0], help="probe seeds (contexts and init)")
    p.add_argument("--json", default="")
    a = p.parse_args()
    if a.contexts <= 0 or a.steps <= 0:
        p.error(f"--contexts and --steps must be positive, got {a.contexts}, {a.steps}")
    run = zsbfm.load(a.run)
    if run.cfg.h_from != "context":
        raise SystemExit(f"{a.run}: h_from={run.cfg.h_from!r}, expected 'context' (F reads a wall map)")
    env = make_env_for(run.cfg, progress=False)
    agent = make_agent(run.cfg, env)
    params = jax.tree_util.tree_map(lambda x: x[0], run.params)
    varies = varying_cells(env)[1:-1, 1:-1].reshape(-1)
    for seed in a.seeds:
        probe_seed(a, run, agent, params, env, varies, seed)


def probe_seed(a, run, agent, params, env, varies, seed: int):
    """Fit and evaluate one probe (module docstring); prints and appends its row."""
    k_train, k_test, k_init = jax.random.split(jax.random.PRNGKey(100 + seed), 3)
    x_train, y_train = encode_contexts(agent, params, env, "train", a.contexts, k_train)
    x_test, y_test = encode_contexts(agent, params, env, "test", a.contexts, k_test)
    error = lambda prob, y: float(np.mean(np.abs(np.round(np.clip(prob, 0, 1)) - y)[:, varies]))

    # the run's own head as F reads it (h_of_mu: c(mu), or sigmoid of c's logits with context_loss="bce")
    linear = lambda x: np.asarray(agent.h_of_mu(params.enc, jnp.asarray(x)))
    net = ProbeMLP(n_out=y_train.shape[1])
    mean, std = x_train.mean(0), x_train.std(0) + 1e-6
    norm = lambda x: (jnp.asarray(x) - mean) / std
    probe = net.init(k_init, norm(x_train[:2]))
    opt = optax.adam(1e-3)
    opt_state = opt.init(probe)

    @jax.jit
    def step(probe, opt_state, x, y):
        loss = lambda q: optax.sigmoid_binary_cross_entropy(net.apply(q, x), y).mean()
        grads = jax.grad(loss)(probe)
        updates, opt_state = opt.update(grads, opt_state)
        return optax.apply_updates(probe, updates), opt_state

    rng = np.random.default_rng(seed)
    for _ in range(a.steps):
        b = rng.integers(0, len(x_train), 256)
        probe, opt_state = step(probe, opt_state, norm(x_train[b]), jnp.asarray(y_train[b]))
    prob = lambda x: np.asarray(jax.nn.sigmoid(net.apply(probe, norm(x))))

    def probe_h(agent, params, context):
        return jnp.round(jax.nn.sigmoid(net.apply(probe, (agent.context_mu(params, context) - mean) / std)))

    out = {"run": a.run, "seed": seed, "contexts": a.contexts, "steps": a.steps,
           "linear_head_map_error": [error(linear(x_train), y_train), error(linear(x_test), y_test)],
           "probe_map_error": [error(prob(x_train), y_train), error(prob(x_test), y_test)]}
    for split in ("train", "test"):
        score, valid = zsbfm.evaluate(run, split=split, protocol="paper", agent=with_context_h(agent, probe_h))
        out[f"probe/{split}/paper"] = float(np.mean(protocol_score(np.asarray(score), np.asarray(valid))))
    print(f"seed {seed}: rounded map error on the varying cells, train / held-out: the run's linear head "
          f"{out['linear_head_map_error'][0]:.3f} / {out['linear_head_map_error'][1]:.3f}, the MLP probe "
          f"{out['probe_map_error'][0]:.3f} / {out['probe_map_error'][1]:.3f}; F given the probe's map "
          f"(paper): {out['probe/train/paper']:.2f} / {out['probe/test/paper']:.2f}")
    if a.json:
        with open(a.json, "a") as f:
            f.write(json.dumps(out) + "\n")


if __name__ == "__main__":
    main()
