"""Can the oracle's F and B fit the exact 20-layout uniform-walk measure by plain regression?

The oracle's networks (d = 100, CPU-preset widths, F told the one-hot layout id), trained by
Adam at batch 256 (s, a) rows x every s+ (rho-weighted) on the squared error of
F(s, a, h)^T B(s+) against M(s, a, s+) / rho(s+), the exact measure P (I - gamma P_pi)^-1:
no bootstrapping, no target network. Prints the relative error (as exact_measure.py) and the
greedy dense success of the fit every 2000 steps. Beside a TD-trained run of the same nets,
this separates what the networks can represent from what TD learning reaches.

    python experiments/fb_diagnostics/supervised_fit.py [steps=10000] [lr=1e-3] [gamma=0.95]
"""
import sys, time, numpy as np, jax, jax.numpy as jnp, optax
import zsbfm
from zsbfm.agents import make_agent, Task
from exact_measure import exact_measure, greedy_dense
steps = int(sys.argv[1]) if len(sys.argv) > 1 else 10000
lr = float(sys.argv[2]) if len(sys.argv) > 2 else 1e-3
gamma = float(sys.argv[3]) if len(sys.argv) > 3 else 0.95
cfg = zsbfm.Config.preset("fourrooms", "oracle", d=100, target_policy="uniform", gamma=gamma)
env = zsbfm.make_env("fourrooms", n_train=20); agent = make_agent(cfg, env)
walls = np.asarray(env.contexts("train").walls); L = 20; S = 11; N = 121
Ms = np.stack([exact_measure(walls[l], cfg.gamma) for l in range(L)])       # [L, N, A, N]
free = ~walls.reshape(L, N)
rho = free.mean(0) / free.mean(0).sum()                                      # ~ data's rho
target = Ms / rho[None, None, None, :].clip(1e-9)                             # density ratio
rows = np.array([(l, s) for l in range(L) for s in range(N) if free[l, s]])
cells = np.asarray(env.states())
params = agent.init_fb_params(*jax.random.split(jax.random.PRNGKey(0)))
opt = optax.adam(lr); st = opt.init(params)
Tj, rhoj, cellsj, rowsj = map(jnp.asarray, (target, rho, cells, rows))
def loss(p, idx):
    l, s = rowsj[idx, 0], rowsj[idx, 1]
    h = jax.nn.one_hot(l, L); z = jnp.zeros((idx.shape[0], cfg.d))
    F = agent.forward(p.F, cellsj[s], Task(z=z, h=h)).mean(0)          # [n, A, d]
    B = agent.backward(p.B, cellsj)                                  # [N, d]
    pred = jnp.einsum("nad,md->nam", F, B)
    return jnp.mean(jnp.sum(rhoj * (pred - Tj[l, s]) ** 2, -1))
@jax.jit
def step(p, st, k):
    idx = jax.random.randint(k, (256,), 0, rows.shape[0])
    g = jax.grad(loss)(p, idx); u, st = opt.update(g, st, p); return optax.apply_updates(p, u), st
def rel_err(p):
    err = num = 0.0; oks = []
    B = np.asarray(agent.backward(p.B, cellsj))
    for l in range(L):
        F = np.asarray(agent.forward(p.F, cellsj, Task(z=jnp.zeros((N, cfg.d)), h=jnp.broadcast_to(jax.nn.one_hot(l, L), (N, L)))).mean(0))
        Mh = np.einsum("sad,td->sat", F, B) * rho; f = free[l]
        err += np.sum((Mh - Ms[l])[f][:, :, f] ** 2); num += np.sum(Ms[l][f][:, :, f] ** 2)
        if l < 4: oks.append(greedy_dense(Mh, walls[l], (1, 1)))
    return np.sqrt(err / num), np.mean(oks)
key = jax.random.PRNGKey(1); t = time.time()
for i in range(steps):
    key, k = jax.random.split(key); params, st = step(params, st, k)
    if (i + 1) % 2000 == 0: print(i + 1, "rel err, greedy dense (4 layouts)", rel_err(params), f"{time.time()-t:.0f}s", flush=True)
