"""Diagnostic: FB conditioned on the TRUE layout (one-hot id as h), on train layouts.

If this upper bound is not above FB, the bottleneck is FB training, not the encoder.
Success on the train layouts is printed every --every steps, to see how it scales.
    python experiments/oracle_h_diagnostic.py [--steps 40000] [--every 10000] [--set batch_size=512]
"""
import argparse
import time

import jax
import jax.numpy as jnp

import zsbfm
from zsbfm.agents import Task, make_agent
from zsbfm.agents.fb import FBAgent
from zsbfm.data import collect
from zsbfm.evaluate import rollout

p = argparse.ArgumentParser()
p.add_argument("--env", default="fourrooms")
p.add_argument("--steps", type=int, default=10_000)
p.add_argument("--every", type=int, default=10_000)
p.add_argument("--set", nargs="*", default=[])
a = p.parse_args()

cfg = zsbfm.Config.preset(a.env, "bfb", h_dim=20).with_overrides(a.set)
env = zsbfm.make_env(a.env, n_train=cfg.n_train_layouts)
L = cfg.n_train_layouts
agent = make_agent(cfg, env)
ds = jax.jit(lambda k: collect(env, k, env.contexts("train"), cfg.episodes_per_layout))(jax.random.PRNGKey(0))
st = agent.init(jax.random.PRNGKey(1))
st = st.replace(h_table=3.0 * jax.nn.one_hot(ds.context_id, L)[:, None, :])
chunk = jax.jit(lambda s, k: jax.lax.scan(lambda s, k: FBAgent.update(agent, s, ds, k), s, jax.random.split(k, a.every)))
ctxs = env.contexts("train")
goals = jax.vmap(env.eval_goals)(ctxs)


@jax.jit
def success(params, key):
    def one(ctx, gs, i, k):
        h = 3.0 * jax.nn.one_hot(i, L)

        def g(goal, kk):
            task = Task(z=agent.backward(params.B, goal), h=h)
            _, _, r = rollout(env, kk, ctx, lambda k2, o: agent.act(params, o, task, k2), cfg.eval_episode_len,
                              goal=goal, start=env.eval_start(ctx))
            return jnp.any(r > 0)
        return jax.vmap(g)(gs, jax.random.split(k, gs.shape[0]))
    return jax.vmap(one)(ctxs, goals, jnp.arange(L), jax.random.split(key, L)).mean()


key = jax.random.PRNGKey(2)
t0 = time.time()
for i in range(a.steps // a.every):
    key, k_train, k_eval = jax.random.split(key, 3)
    st, m = chunk(st, k_train)
    print(f"step {(i + 1) * a.every:6d}  oracle-h train success {float(success(st.params, k_eval)):.3f}  "
          f"fb_loss {float(m['fb_loss'][-100:].mean()):.3f}  {time.time() - t0:.0f} s", flush=True)
