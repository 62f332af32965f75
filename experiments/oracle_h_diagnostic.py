"""Diagnostic: FB conditioned on the TRUE layout (one-hot id as h), on train layouts.

If this upper bound is not above FB, the bottleneck is FB training, not the encoder.
    python experiments/oracle_h_diagnostic.py
"""
import jax, jax.numpy as jnp, numpy as np, zsbfm, time
from zsbfm.agents import make_agent, Task
from zsbfm.data import collect
from zsbfm.evaluate import rollout
from zsbfm.agents.fb import FBAgent
cfg = zsbfm.Config.preset("fourrooms", "bfb", h_dim=20)
env = zsbfm.make_env("fourrooms", n_train=20)
agent = make_agent(cfg, env)
ds = jax.jit(lambda k: collect(env, k, env.contexts("train"), 500))(jax.random.PRNGKey(0))
st = agent.init(jax.random.PRNGKey(1))
st = st.replace(h_table=3.0 * jax.nn.one_hot(ds.context_id, 20)[:, None, :])
f = jax.jit(lambda s, k: jax.lax.scan(lambda s, k: FBAgent.update(agent, s, ds, k), s, jax.random.split(k, 10000)))
t = time.time(); st, m = f(st, jax.random.PRNGKey(2)); jax.block_until_ready(st); print("train s", time.time() - t)
ctxs = env.contexts("train"); goals = jax.vmap(env.eval_goals)(ctxs)
def one(ctx, gs, i, k):
    h = 3.0 * jax.nn.one_hot(i, 20)
    def g(goal, kk):
        task = Task(z=agent.backward(st.params.B, goal), h=h)
        _, _, r = rollout(env, kk, ctx, lambda k2, o: agent.act(st.params, o, task, k2), 100, goal=goal, start=env.eval_start(ctx))
        return jnp.any(r > 0)
    return jax.vmap(g)(gs, jax.random.split(k, gs.shape[0]))
succ = jax.jit(jax.vmap(one))(ctxs, goals, jnp.arange(20), jax.random.split(jax.random.PRNGKey(3), 20))
print("oracle-h FB train success", float(succ.mean()))
