"""The random keys of a run's seeds, below both training and evaluation.

A run's seed i trains with `seed_keys(cfg)[i]` and evaluates with `eval_key` of that key,
so the host driver (zsbfm.train), its learning curve, its final scores and a later
`zsbfm.evaluate(run)` all draw the same tasks and episodes.
"""

from __future__ import annotations

import jax


def seed_keys(cfg) -> jax.Array:
    """One independent key per seed of the run: split(PRNGKey(cfg.seed), cfg.num_seeds)."""
    return jax.random.split(jax.random.PRNGKey(cfg.seed), cfg.num_seeds)


def eval_key(seed_key: jax.Array) -> jax.Array:
    """The key of a seed's evaluations: a function of the seed's key only, so a run's
    learning curve, its final scores and `zsbfm.evaluate(run)` all use the same tasks."""
    return jax.random.fold_in(seed_key, 1)
