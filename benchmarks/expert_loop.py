"""Speed of the AntWind TD3 expert's loop (zsbfm.data.expert): ms per iteration (one env step
of num_envs MJX envs, then updates_per_iter TD3 updates) of ExpertSettings variants, after
the warm-up (so every iteration updates), each compiled with XLA's default options and with
zsbfm's (cpu_tuning: YNNPACK fusions off), best of 3 chunks.

    python benchmarks/expert_loop.py
"""

from __future__ import annotations

import time

import jax

import zsbfm
from zsbfm.cpu_tuning import YNN_OPTION
from zsbfm.data.expert import ExpertSettings, TD3Expert

VARIANTS = {
    "the preset (hidden (256, 256), batch 256, 8 updates / iteration)": {},
    "16 updates / iteration": dict(updates_per_iter=16),
    "hidden (128, 128)": dict(hidden=(128, 128)),
    "batch 512": dict(batch_size=512),
}
OPTIONS = {"default": {}, "ynnpack off": {YNN_OPTION: ""}}


def ms_per_iteration(env, overrides, options, chunks=3):
    s = ExpertSettings(**{"num_timesteps": 64 * 100 * 6, **overrides})
    agent = TD3Expert(env, s)
    st = jax.jit(agent.init)(jax.random.PRNGKey(0))
    lowered = jax.jit(agent.run_chunk).lower(st)
    compiled = {name: lowered.compile(compiler_options=opts) for name, opts in options.items()}
    st = compiled["default"](compiled["default"](st))  # past the warm-up's random actions
    best = dict.fromkeys(options, float("inf"))
    for _ in range(chunks):
        for name, fn in compiled.items():
            t = time.perf_counter()
            st = jax.block_until_ready(fn(st))
            best[name] = min(best[name], (time.perf_counter() - t) / s.chunk * 1e3)
    return best


def main():
    env = zsbfm.make_env("antwind")
    print(f"| TD3 expert loop, ms / iteration (64 envs) | {' | '.join(OPTIONS)} |\n|---|---|---|")
    for name, over in VARIANTS.items():
        ms = ms_per_iteration(env, over, OPTIONS)
        print(f"| {name} | {' | '.join(f'{v:.1f}' for v in ms.values())} |", flush=True)


if __name__ == "__main__":
    main()
