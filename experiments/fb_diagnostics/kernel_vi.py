"""Diagnose an oracle/FB run: is B's kernel reward solvable by exact VI (B bottleneck) vs F's greedy?"""
import sys, numpy as np, jax, jax.numpy as jnp
import zsbfm
from zsbfm.agents import make_agent, Task
from zsbfm.envs import make_env, index_contexts
from zsbfm.envs.gridworld import ACTION_DELTAS

run = zsbfm.load(sys.argv[1]); cfg = run.cfg
split = sys.argv[2] if len(sys.argv) > 2 else "train"
env = make_env(cfg.env, n_train=cfg.n_train_layouts, episode_len=cfg.episode_len)
agent = make_agent(cfg, env)
params = run.seed_params(0)
S = env.size
cells = np.array([(x, y) for y in range(S) for x in range(S)], np.float32)
Ball = np.asarray(agent.backward(params.B, jnp.asarray(cells)))
ctxs = env.contexts(split)
n = ctxs.walls.shape[0]
goals = np.asarray(env.eval_goals(index_contexts(ctxs, 0))).astype(int)
start = tuple(np.asarray(env.eval_start(index_contexts(ctxs, 0))).astype(int))
g_ = cfg.gamma
vi_succ, fb_succ, vi_true = [], [], []
def step(walls, x, y, a):
    dx, dy = ACTION_DELTAS[a]; nx, ny = x + dx, y + dy
    return (x, y) if walls[ny, nx] else (nx, ny)
for l in range(min(n, 20)):
    walls = np.asarray(ctxs.walls[l])
    for g in goals:
        zg = Ball[g[1] * S + g[0]]
        r = (Ball @ zg).reshape(S, S)  # r[y, x]
        V = np.zeros((S, S)); 
        for _ in range(300):
            Q = np.zeros((S, S, 4))
            for y in range(S):
                for x in range(S):
                    if walls[y, x]: continue
                    for a in range(4):
                        nx, ny = step(walls, x, y, a); Q[y, x, a] = r[ny, nx] + g_ * V[ny, nx]
            V = Q.max(-1)
        # rollout VI policy
        x, y = start; ok = False
        for t in range(100):
            x, y = step(walls, x, y, int(Q[y, x].argmax()))
            if (x, y) == tuple(g): ok = True; break
        vi_succ.append(ok)
    # FB greedy rollouts via the agent
    from zsbfm.evaluate import context_episode, goal_rollout
    ctx = index_contexts(ctxs, l)
    context = context_episode(env, jax.random.PRNGKey(0), ctx, cfg.context_len)
    for g in goals:
        ok, obs = goal_rollout(agent, env, params, jax.random.PRNGKey(1), ctx, context, jnp.asarray(g, jnp.float32), 100)
        fb_succ.append(bool(ok))
print(f"{sys.argv[1]} {split}: VI on B-kernel reward success {np.mean(vi_succ):.3f}; FB greedy {np.mean(fb_succ):.3f}")
# kernel sharpness: mean over goals of B(g)^T B(neighbour)/d
print("kernel B(g).B(s)/d at goal neighbours:", [[round(float(Ball[(g[1]+dy)*S+g[0]+dx] @ Ball[g[1]*S+g[0]])/cfg.d,2) for dx,dy in ACTION_DELTAS] for g in goals])
