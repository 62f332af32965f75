"""Learned Q = F^T B(g) vs exact Q* of the B-kernel reward r(s') = B(s')^T B(g) (VI, true walls).
Reports, over train layouts x all goal cells x free states: the share of states where the learned
greedy action is optimal for Q*, and the relative error of V."""
import sys, numpy as np, jax, jax.numpy as jnp
import zsbfm
from zsbfm.agents import make_agent, Task
from zsbfm.envs import make_env, index_contexts
from zsbfm.envs.gridworld import ACTION_DELTAS
from zsbfm.evaluate import context_episode
run = zsbfm.load(sys.argv[1]); cfg = run.cfg
nl = int(sys.argv[2]) if len(sys.argv) > 2 else 4
env = make_env(cfg.env, n_train=cfg.n_train_layouts, episode_len=cfg.episode_len)
agent = make_agent(cfg, env)
params = run.seed_params(0)
S = env.size; g_ = cfg.gamma
cells = jnp.asarray([(x, y) for y in range(S) for x in range(S)], jnp.float32)
Ball = np.asarray(agent.backward(params.B, cells))
ctxs = env.contexts("train")
agree, relerr = [], []
for l in range(min(nl, ctxs.walls.shape[0])):
    ctx = index_contexts(ctxs, l); walls = np.asarray(ctx.walls)
    free = ~walls.reshape(-1)
    nxt = np.zeros((S * S, 4), int)
    for i, (x, y) in enumerate(np.asarray(cells).astype(int)):
        for a, (dx, dy) in enumerate(ACTION_DELTAS):
            nx, ny = x + dx, y + dy
            nxt[i, a] = i if (walls[y, x] or walls[ny, nx]) else ny * S + nx
    context = context_episode(env, jax.random.PRNGKey(0), ctx, cfg.context_len)
    h = agent.context_h(params, context)
    for gi in np.where(free)[0]:
        z = Ball[gi]; r = Ball @ z
        V = np.zeros(S * S)
        for _ in range(200):
            Q = r[nxt] + g_ * V[nxt]; V = Q.max(1)
        task = Task(z=jnp.broadcast_to(jnp.asarray(z), (S * S, cfg.d)), h=jnp.broadcast_to(h, (S * S,) + h.shape))
        Ql = np.asarray(agent.q_values(params, cells, task))
        best = Q >= Q.max(1, keepdims=True) - 1e-6 * np.abs(Q).max()
        m = free & (np.arange(S * S) != gi)
        agree.append(best[np.arange(S * S), Ql.argmax(1)][m].mean())
        relerr.append(np.abs(Ql.max(1) - V)[m].mean() / np.abs(V[m]).mean())
print(f"{sys.argv[1]}: greedy action optimal for Q* on {np.mean(agree):.3f} of states; mean |V-V*|/|V*| {np.mean(relerr):.3f}")
