"""Q spread across the one-hot h of an oracle run, relative to |Q|.
Usage: python experiments/fb_diagnostics/h_sensitivity.py runs/<oracle run> [...]"""
import sys, numpy as np, jax, jax.numpy as jnp, zsbfm
from zsbfm.agents import make_agent, Task
from zsbfm.envs import make_env
for path in sys.argv[1:]:
    run = zsbfm.load(path); cfg = run.cfg
    env = make_env(cfg.env, n_train=cfg.n_train_layouts, episode_len=cfg.episode_len)
    agent = make_agent(cfg, env)
    p = run.seed_params(0)
    S = env.size; H = cfg.n_train_layouts
    cells = jnp.asarray([(x, y) for y in range(1, S-1) for x in range(1, S-1)], jnp.float32)
    B = agent.backward(p.B, cells)
    z = B[jnp.arange(cells.shape[0]) % B.shape[0]]
    Fs = []
    for l in range(H):
        h = jnp.broadcast_to(jax.nn.one_hot(l, H), (cells.shape[0], H))
        Fs.append(np.asarray(agent.q_values(p, cells, Task(z=z[::-1], h=h))))
    Fs = np.stack(Fs)  # [H, n, A]
    between = np.abs(Fs - Fs.mean(0)).mean(); scale = np.abs(Fs).mean()
    print(path, f"Q spread across h / |Q|: {between/scale:.4f}")
