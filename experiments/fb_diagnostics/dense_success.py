"""Dense goal-reaching score of a saved run: from the eval start, every free cell as a goal,
on every train layout (and test layouts, at most 20 of each). Greedy rollouts of 100 steps
on the gridworlds; on pointmass the goals are the free cells' centres (world units) and the
rollouts are the evaluation's own length (250 steps). Seed-averaged.

    python experiments/fb_diagnostics/dense_success.py [--swap-context] runs/<name> [...]

--swap-context: the context episode (hence h) comes from the next layout of the split
(layout i is played with layout i+1's context): if the score holds, F ignores h."""
import sys, numpy as np, jax, jax.numpy as jnp
import zsbfm
from zsbfm.agents import make_agent
from zsbfm.envs import make_env, index_contexts
from zsbfm.evaluate import context_episode, goal_rollout

swap = "--swap-context" in sys.argv
for path in [a for a in sys.argv[1:] if a != "--swap-context"]:
    run = zsbfm.load(path); cfg = run.cfg
    env = make_env(cfg.env, n_train=cfg.n_train_layouts, episode_len=cfg.episode_len)
    agent = make_agent(cfg, env)
    if cfg.env == "pointmass":
        from zsbfm.envs.pointmass import SIZE as S, UNIT
        cells = (jnp.asarray([(x, y) for y in range(S) for x in range(S)], jnp.float32) + 0.5) * UNIT
        length = cfg.eval_episode_len
    else:
        S, length = env.size, 100
        cells = jnp.asarray([(x, y) for y in range(S) for x in range(S)], jnp.float32)
    out = {}
    for split in ("train", "test"):
        ctxs = env.contexts(split)
        n = min(ctxs.walls.shape[0], 20)

        def one(params, ctx, ctx_h, k):
            context = context_episode(env, k, ctx_h, cfg.context_len)
            ok, _ = jax.vmap(lambda g: goal_rollout(agent, env, params, k, ctx, context, g, length))(cells)
            free = ~ctx.walls.reshape(-1)
            start = env.eval_start(ctx)
            free = free & jnp.any(jnp.abs(cells - start) > 1e-3, -1)
            return jnp.sum(ok * free) / jnp.sum(free)

        f = jax.jit(jax.vmap(jax.vmap(one, (None, 0, 0, 0)), (0, None, None, None)))
        sub = jax.tree_util.tree_map(lambda x: x[:n], ctxs)
        sub_h = jax.tree_util.tree_map(lambda x: jnp.roll(x, -1, axis=0), sub) if swap else sub
        r = np.asarray(f(run.params, sub, sub_h, jax.random.split(jax.random.PRNGKey(0), n)))  # [seeds, layouts]
        out[split] = r
    print(f"{path}{' (contexts swapped)' if swap else ''}: dense success train {out['train'].mean():.3f} (per seed {np.round(out['train'].mean(1),3).tolist()}), "
          f"test {out['test'].mean():.3f}; official {run.results['train']} / {run.results['test']}")
