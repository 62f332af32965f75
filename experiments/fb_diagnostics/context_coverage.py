"""What one test-time context episode can tell about a gridworld layout, for any encoder.

    python experiments/fb_diagnostics/context_coverage.py [--env fourrooms doors] [--episodes 20]
        [--context-episodes 1 2 4 8] [--json results/context_coverage.json]

At test time a belief agent infers h from one reward-free episode of the behaviour policy
(`evaluate.context_episode`: the same policy and length as the training episodes). The
episode reveals a cell of the layout only by visiting it (free) or by bumping into it (a
move that left the agent in place: a wall). This counts, over fresh episodes of the 20
held-out layouts (and of the train layouts, the same numbers up to sampling):
- the doors (the free cells of the wall lines) that the episode passes through: the fraction of the layout's doors, and how many episodes pass all / none;
- the varying cells (walled in some layout of the family, free in another) it reveals.
What an episode does not reveal, no encoder can read from it: it is left to the prior over
the family (and, for a train layout, to recognising it from the part seen).
--context-episodes: the same for contexts of K episodes of a layout (Config.context_episodes),
what their union reveals (the episodes of a layout are split into groups of K).
"""
from __future__ import annotations

import argparse
import json

import jax
import jax.numpy as jnp
import numpy as np

import zsbfm
from zsbfm.config import Config
from zsbfm.data import collect


def doors(walls: np.ndarray) -> list[tuple[int, int]]:
    """(y, x) of the doors: free interior cells on a wall line, a row or column whose interior
    is at least half wall (Four-Rooms: x = c and y = r; Doors: x = 3 and x = 5)."""
    inner = walls[1:-1, 1:-1]
    wall_col, wall_row = inner.mean(0) >= 0.5, inner.mean(1) >= 0.5
    return [(y + 1, x + 1) for y, x in zip(*np.nonzero(~inner)) if wall_col[x] or wall_row[y]]


def revealed(env, obs, actions) -> jax.Array:
    """bool[H, W]: the cells an episode (obs [T+1, 2] as (x, y), actions int[T]) visited or
    bumped into (a move that left it in place), env.revealed_features on the whole grid (the
    border, a wall in every layout, counted as not shown)."""
    inner = env.revealed_features(obs[:-1], actions, obs[1:]).reshape(env.size - 2, env.size - 2)
    return jnp.zeros((env.size, env.size), bool).at[1:-1, 1:-1].set(inner)


def varying_cells(env) -> np.ndarray:
    """bool[H, W]: the cells walled in some layout of the family (train or test) and free in another."""
    every = np.concatenate([np.asarray(env.contexts(s).walls) for s in ("train", "test")])
    return every.min(0) != every.max(0)


def door_stats(seen_all, walls, cid) -> dict:
    """Door coverage of contexts: seen_all bool[n, H, W] (what each context revealed), walls
    [layouts, H, W], cid int[n] (each context's layout)."""
    door_frac = np.asarray([np.mean([seen[c] for c in doors(walls[cid[e]])]) for e, seen in enumerate(seen_all)])
    return {"door_fraction_passed": float(door_frac.mean()),
            "episodes_passing_all_doors": float(np.mean(door_frac == 1)),
            "episodes_passing_no_door": float(np.mean(door_frac == 0))}


def coverage(env_name: str, episodes: int, seed: int, context_episodes=()) -> dict:
    cfg = Config.preset(env_name, "bfb", "cpu")
    env = zsbfm.make_env(env_name, n_train=cfg.n_train_layouts)
    walls = {s: np.asarray(env.contexts(s).walls) for s in ("train", "test")}
    varies = varying_cells(env)
    out = {"env": env_name, "episode_len": env.episode_len, "episodes_per_layout": episodes,
           "varying_cells": int(varies.sum())}
    for split, w in walls.items():
        ds = jax.jit(lambda k: collect(env, k, env.contexts(split), episodes))(jax.random.PRNGKey(seed))
        cid = np.asarray(ds.context_id)
        seen_all = np.asarray(jax.vmap(lambda o, a_: revealed(env, o, a_))(ds.obs, ds.action))
        out[split] = {"doors_per_layout": float(np.mean([len(doors(x)) for x in w])),
                      **door_stats(seen_all, w, cid),
                      "varying_cells_revealed": float(np.mean([s[varies].mean() for s in seen_all]))}
        r = out[split]
        print(f"{env_name} {split} layouts ({len(cid)} episodes of {env.episode_len} steps): "
              f"{r['doors_per_layout']:.0f} doors; an episode passes {r['door_fraction_passed']:.2f} of them, "
              f"all of them in {r['episodes_passing_all_doors']:.2f} of episodes, none in "
              f"{r['episodes_passing_no_door']:.2f}; it reveals {r['varying_cells_revealed']:.2f} of the "
              f"{out['varying_cells']} cells that differ between layouts")
        for k in context_episodes:  # episodes are context-major: groups of k consecutive ones
            groups = episodes // k
            per_layout = seen_all.reshape(len(w), episodes, *seen_all.shape[1:])[:, :groups * k]
            union = per_layout.reshape(len(w) * groups, k, *seen_all.shape[1:]).any(1)
            r.setdefault("by_context_episodes", {})[str(k)] = dict(
                door_stats(union, w, np.repeat(np.arange(len(w)), groups)), contexts=len(w) * groups)
            q = r["by_context_episodes"][str(k)]
            print(f"  contexts of {k:2d} episodes: pass {q['door_fraction_passed']:.2f} of the doors, all of "
                  f"them in {q['episodes_passing_all_doors']:.2f}, none in {q['episodes_passing_no_door']:.2f}")
    return out


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--env", nargs="+", default=["fourrooms", "doors"], choices=["fourrooms", "doors"])
    p.add_argument("--episodes", type=int, default=20, help="fresh episodes per layout")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--context-episodes", nargs="*", type=int, default=[],
                   help="also the door coverage of contexts of this many episodes")
    p.add_argument("--json", default="", help="write the figures to this JSON file")
    a = p.parse_args()
    if a.episodes <= 0:
        p.error(f"--episodes must be a positive integer, got {a.episodes}")
    if any(not 1 <= k <= a.episodes for k in a.context_episodes):
        p.error(f"--context-episodes must be in 1..--episodes={a.episodes}, got {a.context_episodes}")
    res = [coverage(e, a.episodes, a.seed, a.context_episodes) for e in a.env]
    if a.json:
        with open(a.json, "w") as f:
            json.dump(res, f, indent=1)
        print(f"wrote {a.json}")


if __name__ == "__main__":
    main()
