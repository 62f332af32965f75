"""How much a context window can tell about a Pointmass maze: an exact count.

    python experiments/fb_diagnostics/pointmass_ambiguity.py

For 10 behaviour episodes per train maze, the number of train mazes in which every cell
the window visits is free (the mazes the window is consistent with; 1 = identified), for
windows of 100 steps (the preset's context) and 250 (a whole episode). Only visits count,
not collisions, so this bounds the ambiguity from above.
"""
import jax
import numpy as np

import zsbfm
from zsbfm.data.collect import collect
from zsbfm.data.sources import make_env_for

cfg = zsbfm.Config.preset("pointmass", "bfb")
env = make_env_for(cfg, progress=False)
ctx = env.contexts("train")
walls = np.asarray(ctx.walls).reshape(len(ctx.walls), env.n_cells)   # [mazes, cells], row-major
ds = jax.jit(lambda k: collect(env, k, ctx, 10))(jax.random.PRNGKey(0))
cells = np.asarray(env.cell_index(ds.obs))                            # [episodes, T + 1]
for L in (100, 250):
    counts, seen = [], []
    for e in range(cells.shape[0]):
        visited = np.zeros(env.n_cells, bool)
        visited[cells[e, :L + 1]] = True
        counts.append((~(walls & visited[None]).any(1)).sum())
        seen.append(visited.sum())
    counts = np.asarray(counts)
    print(f"window {L}: {np.mean(seen):.1f} cells visited; consistent train mazes: mean {counts.mean():.1f} "
          f"of {len(walls)}, median {np.median(counts):.0f}; identified (exactly 1): {np.mean(counts == 1):.2f}; "
          f"best possible accuracy of a guess among them: {np.mean(1 / counts):.2f}")
