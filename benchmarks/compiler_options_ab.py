"""XLA's YNNPACK fusions on or off (zsbfm/cpu_tuning.py): updates/s of each algo's CPU-preset
chunk, compiled twice in one process (XLA's default options, then zsbfm's), timed in
alternation, best of two rounds; the encoder phase too for the belief algos.

    python benchmarks/compiler_options_ab.py [fb bfb rfb oracle hilp lap]
"""

from __future__ import annotations

import sys

import jax
import jax.numpy as jnp

sys.path.insert(0, __file__.rsplit("/", 1)[0])
from throughput import timed  # noqa: E402

import zsbfm  # noqa: E402
from zsbfm.cpu_tuning import YNN_OPTION  # noqa: E402
from zsbfm.train import make_train, seed_keys  # noqa: E402

STEPS = 200
OPTIONS = {"default": {}, "ynnpack off": {YNN_OPTION: ""}}


def main(algos):
    print(f"| updates/s, fourrooms cpu preset, 1 seed | {' | '.join(OPTIONS)} | ratio |\n|---|---|---|---|")
    for algo in algos:
        cfg = zsbfm.Config.preset("fourrooms", algo, "cpu", num_seeds=1, chunk_steps=STEPS)
        cfg = cfg.replace(steps=cfg.steps // STEPS * STEPS, enc_steps=max(STEPS, cfg.enc_steps // STEPS * STEPS))
        tr = make_train(cfg)
        carry = jax.jit(jax.vmap(tr.init))(seed_keys(cfg))
        ds = jax.jit(jax.vmap(tr.collect_data))(carry)
        phases = {"FB phase": cfg.num_chunks - 1}
        if algo in ("bfb", "rfb"):
            phases["encoder phase"] = 0
        for phase, chunk in phases.items():
            args = (carry, ds, jnp.int32(chunk), {})
            lowered = jax.jit(jax.vmap(tr.run_chunk, in_axes=(0, 0, None, None))).lower(*args)
            compiled = {name: lowered.compile(compiler_options=opts) for name, opts in OPTIONS.items()}
            rate = dict.fromkeys(OPTIONS, 0.0)
            for _ in range(2):
                for name, fn in compiled.items():
                    rate[name] = max(rate[name], STEPS / timed(lambda: fn(*args), repeat=3))
            a, b = rate.values()
            print(f"| {algo}, {phase} | {a:.1f} | {b:.1f} | {b / a:.2f} |", flush=True)


if __name__ == "__main__":
    main(sys.argv[1:] or ["fb", "bfb", "rfb", "oracle", "hilp", "lap"])
