"""The non-finite guard: a run notices within one chunk when a seed's losses or parameters
stop being finite numbers, and never checkpoints such a state.

In the compiled chunk (`zsbfm.train.make_train`, `run_chunk`), `all_finite` reduces the
chunk's mean losses and the whole agent state of a seed to one flag; a seed whose flag is
false keeps the state it started the chunk with (`keep_finite`), so no checkpoint ever holds
a NaN. The flag leaves the program with the chunk's metrics (the one transfer per chunk).
On the host, Config.on_nonfinite decides what follows: "stop" ends the run with
`NonFiniteError`, whose one-line message names the seed(s), the chunk, the first non-finite
loss term and its last finite value (`describe`); "drop" marks the seed dropped in
metrics.jsonl, results.json and the plots and trains the other seeds on.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp


class NonFiniteError(RuntimeError):
    """A seed's losses or parameters went non-finite (Config.on_nonfinite="stop", or every
    seed of an on_nonfinite="drop" run). `rows`: the seed rows; `chunk`: the chunk (1-based)."""

    def __init__(self, message: str, rows: list[int], chunk: int):
        super().__init__(message)
        self.rows, self.chunk = rows, chunk


def all_finite(tree) -> jax.Array:
    """bool[]: every floating-point entry of `tree` is finite (one reduction; traceable)."""
    flags = [jnp.all(jnp.isfinite(x)) for x in jax.tree_util.tree_leaves(tree)
             if jnp.issubdtype(jnp.asarray(x).dtype, jnp.inexact)]
    return jnp.all(jnp.stack(flags)) if flags else jnp.bool_(True)


def keep_finite(finite: jax.Array, new, old):
    """`new` where `finite`, else `old` (leaf by leaf; traceable): a seed whose chunk went
    non-finite keeps the state it started the chunk with."""
    return jax.tree_util.tree_map(lambda n, o: jnp.where(finite, n, o), new, old)


def _is_finite(v) -> bool:
    return v is not None and math.isfinite(v)


def loss_order(names) -> list[str]:
    """The order terms are named in: loss terms (names holding "loss") first, then the
    other metrics, each alphabetically."""
    return sorted(names, key=lambda k: ("loss" not in k, k))


def describe(row: dict, names, rows: list[int], history: list[dict], row_name) -> str:
    """What went non-finite for each of `rows` in metrics `row` ({name: [value per row]}):
    the first non-finite term of `names` and its last finite value in `history` (earlier
    metrics rows), or that only the parameters did. row_name(i) names row i ("seed 1")."""
    parts = []
    for i in rows:
        term = next((k for k in loss_order(names) if not _is_finite(row[k][i])), None)
        if term is None:
            parts.append(f"{row_name(i)}: parameters non-finite (losses finite)")
            continue
        last = next(((r[term][i], r["chunk"]) for r in reversed(history)
                     if term in r and isinstance(r[term], list) and _is_finite(r[term][i])), None)
        was = f"last finite {last[0]:.4g} in chunk {last[1]}" if last else "no finite value before"
        parts.append(f"{row_name(i)}: {term} = {row[term][i]} ({was})")
    return "; ".join(parts)
