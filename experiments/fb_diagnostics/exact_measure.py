"""How close is a gridworld run's learned measure to the exact one? (uniform target policy)

For each train layout l (at most 20) of a run trained with target_policy=uniform, compares
M_hat(s, a, s+) = F(s, a, z, h_l)^T B(s+) rho(s+) (twin mean, rho = the data's next-state
frequency) with the exact successor measure of the uniform random walk,
M = P (I - gamma P_pi)^-1 on the layout's free cells, and reports per seed:
  rel_err:    |M_hat - M|_F / |M|_F over free (s, a) rows and free s+ columns;
  rank_floor: the same error of the best rank-d approximation of all layouts' M stacked
              (one shared B: what F^T B can reach at this d, ignoring rho weighting);
  greedy_ok:  dense success of greedy ascent on M_hat (from the eval start to every free cell),
              and on the exact M (1.0: greedy on the exact random-walk measure reaches every goal).

    python experiments/fb_diagnostics/exact_measure.py [--swap-context] runs/<name> [...]

--swap-context: F gets layout l+1's context (h) for layout l: if rel_err barely rises, F
ignores h (it predicts the layout-averaged measure).
"""
import sys

import jax
import jax.numpy as jnp
import numpy as np

import zsbfm
from zsbfm.agents import Task, make_agent
from zsbfm.envs import index_contexts, make_env
from zsbfm.envs.gridworld import ACTION_DELTAS


def transition_matrix(walls):
    S = walls.shape[0]
    N = S * S
    P = np.zeros((N, 4, N))
    for y in range(S):
        for x in range(S):
            for a, (dx, dy) in enumerate(ACTION_DELTAS):
                nx, ny = x + dx, y + dy
                if walls[y, x] or walls[ny, nx]:
                    nx, ny = x, y
                P[y * S + x, a, ny * S + nx] = 1.0
    return P


def exact_measure(walls, gamma):
    P = transition_matrix(walls)
    N = P.shape[0]
    return np.einsum("san,nm->sam", P, np.linalg.inv(np.eye(N) - gamma * P.mean(1)))


def greedy_dense(M, walls, start):
    S = walls.shape[0]
    ok, n = 0, 0
    for gy in range(S):
        for gx in range(S):
            if walls[gy, gx] or (gx, gy) == start:
                continue
            n += 1
            x, y = start
            for _ in range(100):
                dx, dy = ACTION_DELTAS[int(np.argmax(M[y * S + x, :, gy * S + gx]))]
                if not walls[y + dy, x + dx]:
                    x, y = x + dx, y + dy
                if (x, y) == (gx, gy):
                    ok += 1
                    break
    return ok / n


def main():
    SWAP = "--swap-context" in sys.argv
    for path in [a for a in sys.argv[1:] if a != "--swap-context"]:
        run = zsbfm.load(path)
        cfg = run.cfg
        if cfg.target_policy != "uniform":
            print(f"{path}: target_policy={cfg.target_policy!r}; this compares with the uniform walk's measure")
        env = make_env(cfg.env, n_train=cfg.n_train_layouts, episode_len=cfg.episode_len)
        agent = make_agent(cfg, env)
        ctxs = env.contexts("train")
        n = min(cfg.n_train_layouts, 20)
        cells = env.states()
        S = env.size
        start = tuple(int(v) for v in np.asarray(env.eval_start(index_contexts(ctxs, 0))))
        from zsbfm.data import collect
        ds = collect(env, jax.random.PRNGKey(0), ctxs, cfg.episodes_per_layout)
        nxt = np.asarray(env.state_index(ds.obs[:, 1:])).reshape(-1)
        rho = np.bincount(nxt, minlength=S * S) / nxt.size
        Ms = [exact_measure(np.asarray(ctxs.walls[l]), cfg.gamma) for l in range(n)]
        frees = [~np.asarray(ctxs.walls[l]).reshape(-1) for l in range(n)]
        X = np.concatenate([(M * f[:, None, None]).reshape(-1, S * S) for M, f in zip(Ms, frees)], 0)
        U, sv, Vt = np.linalg.svd(X, full_matrices=False)
        Xd = ((U[:, :cfg.d] * sv[:cfg.d]) @ Vt[:cfg.d]).reshape(n, S * S, 4, S * S)
        floor = np.linalg.norm(Xd - X.reshape(n, S * S, 4, S * S)) / np.linalg.norm(X)
        exact_ok = np.mean([greedy_dense(M, np.asarray(ctxs.walls[l]), start) for l, M in enumerate(Ms[:4])])
        seeds = jax.tree_util.tree_leaves(run.params)[0].shape[0]
        for seed in range(seeds):
            params = run.seed_params(seed)
            errs, oks = [], []
            B = np.asarray(agent.backward(params.B, cells))
            for l in range(n):
                ctx = index_contexts(ctxs, l)
                from zsbfm.evaluate import context_episode
                ctx_h = index_contexts(ctxs, (l + 1) % n) if SWAP else ctx
                h = agent.context_h(params, context_episode(env, jax.random.PRNGKey(l), ctx_h, cfg.context_len))
                z = jnp.asarray(B[start[1] * S + start[0]])
                task = Task(z=jnp.broadcast_to(z, (S * S, cfg.d)), h=jnp.broadcast_to(h, (S * S, h.shape[-1])))
                F = np.asarray(agent.forward(params.F, cells, task).mean(0))           # [N, A, d]
                Mh = np.einsum("sad,td->sat", F, B) * rho[None, None]
                f = frees[l]
                err = np.linalg.norm((Mh - Ms[l])[f][:, :, f]) / np.linalg.norm(Ms[l][f][:, :, f])
                errs.append(err)
                if l < 4:
                    oks.append(greedy_dense(Mh, np.asarray(ctxs.walls[l]), start))
            print(f"{path} seed {seed}: rel_err {np.mean(errs):.3f} (rank-{cfg.d} floor {floor:.3f}); "
                  f"greedy dense on M_hat {np.mean(oks):.3f} (first 4 layouts; exact M {exact_ok:.3f})")


if __name__ == "__main__":
    main()
