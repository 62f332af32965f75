"""How the Q-loss's C^-1 z is computed, timed inside the scanned FB update.

    python benchmarks/qloss_solve.py

The Four-Rooms FB CPU preset (1 seed, chunks of 200 updates) with `agents.fb.q_loss`'s
inverse of C swapped for each variant below. Every variant is compiled first, then timed
in 4 alternating rounds (the best chunk of each), so the rows share the machine's state.
"""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp
from jax.scipy.linalg import cho_factor, cho_solve

import zsbfm
import zsbfm.agents.fb as fb
from zsbfm.train import make_train, seed_keys

ORIGINAL = fb.spd_inverse
VARIANTS = {  # C [d, d] -> what q_loss multiplies z by (C^-1, or a stand-in for timing)
    "Newton-Schulz, 24 steps (ops.spd_inverse, the preset)": ORIGINAL,
    "LAPACK LU (jnp.linalg.solve against I; the Q-loss before)": lambda C: jnp.linalg.solve(C, jnp.eye(C.shape[0])),
    "LAPACK Cholesky (cho_solve)": lambda C: cho_solve(cho_factor(C), jnp.eye(C.shape[0])),
    "C itself, no inverse (timing only, not the loss)": lambda C: C,
}


def chunk_fn(inverse, steps=200):
    fb.spd_inverse = inverse  # read when the update is traced, i.e. at the first call below
    cfg = zsbfm.Config.preset("fourrooms", "fb", "cpu", num_seeds=1, chunk_steps=steps)
    tr = make_train(cfg)
    carry = jax.jit(jax.vmap(tr.init))(seed_keys(cfg))
    ds = jax.jit(jax.vmap(tr.collect_data))(carry)
    f = jax.jit(jax.vmap(tr.run_chunk, in_axes=(0, 0, None, None)))
    run = lambda: f(carry, ds, jnp.int32(1), {})
    jax.block_until_ready(run())  # compile with this variant
    fb.spd_inverse = ORIGINAL
    return run


def main(rounds=4, steps=200):
    runs = {name: chunk_fn(inv, steps) for name, inv in VARIANTS.items()}
    best = {name: float("inf") for name in runs}
    for _ in range(rounds):
        for name, run in runs.items():
            t = time.perf_counter()
            jax.block_until_ready(run())
            best[name] = min(best[name], (time.perf_counter() - t) / steps)
    print("| C^-1 in the Q-loss (fb, fourrooms, cpu preset, 1 seed) | ms / update | updates/s |\n|---|---|---|")
    for name, t in best.items():
        print(f"| {name} | {1e3 * t:.1f} | {1 / t:.1f} |")


if __name__ == "__main__":
    main()
