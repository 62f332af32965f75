"""Dense goal-reaching score of a saved run: from the eval start, every free cell as a goal,
on every train layout (and test layouts). Greedy rollouts, 100 steps. Seed-averaged."""
import sys, numpy as np, jax, jax.numpy as jnp
import zsbfm
from zsbfm.agents import make_agent
from zsbfm.envs import make_env, index_contexts
from zsbfm.evaluate import context_episode, goal_rollout

for path in sys.argv[1:]:
    run = zsbfm.load(path); cfg = run.cfg
    env = make_env(cfg.env, n_train=cfg.n_train_layouts, episode_len=cfg.episode_len)
    agent = make_agent(cfg, env)
    S = env.size
    cells = jnp.asarray([(x, y) for y in range(S) for x in range(S)], jnp.float32)
    out = {}
    for split in ("train", "test"):
        ctxs = env.contexts(split)
        n = min(ctxs.walls.shape[0], 20)

        def one(params, ctx, k):
            context = context_episode(env, k, ctx, cfg.context_len)
            ok, _ = jax.vmap(lambda g: goal_rollout(agent, env, params, k, ctx, context, g, 100))(cells)
            free = ~ctx.walls.reshape(-1)
            start = env.eval_start(ctx)
            free = free & jnp.any(cells != start, -1)
            return jnp.sum(ok * free) / jnp.sum(free)

        f = jax.jit(jax.vmap(jax.vmap(one, (None, 0, 0)), (0, None, None)))
        sub = jax.tree_util.tree_map(lambda x: x[:n], ctxs)
        r = np.asarray(f(run.params, sub, jax.random.split(jax.random.PRNGKey(0), n)))  # [seeds, layouts]
        out[split] = r
    print(f"{path}: dense success train {out['train'].mean():.3f} (per seed {np.round(out['train'].mean(1),3).tolist()}), "
          f"test {out['test'].mean():.3f}; official {run.results['train']} / {run.results['test']}")
