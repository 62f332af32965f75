"""Throughput of the compiled pieces on this machine (prints a Markdown table).

    python benchmarks/throughput.py            # all
    python benchmarks/throughput.py --quick    # smaller sizes

Measures, after one warm-up call (compile excluded):
  - gridworld env steps/s: 4096 vmapped fourrooms envs x 1000 random steps;
  - AntWind env steps/s: MJX, vmapped envs x 100 random steps, beside native MuJoCo (C,
    one thread, the same model and wind force) on the same actions;
  - dataset collection: 1e6 transitions (20 layouts x 500 episodes x 100 steps);
  - update steps/s of each algo's CPU preset, 1 seed and 3 vmapped seeds, and of the paper
    sizes; GFLOP per update from XLA's cost analysis, and the fraction of the f32 matmul
    peak: the best matmul rate measured in the same run (`matmul_rates`, before and after
    the updates).
"""

from __future__ import annotations

import argparse
import platform
import sys
import time

import jax
import jax.numpy as jnp

import zsbfm
from zsbfm.cpu_tuning import compiler_options
from zsbfm.data import collect
from zsbfm.envs import index_contexts, num_contexts
from zsbfm.train import make_train, seed_keys


def timed(fn, *args, repeat=3):
    out = fn(*args)
    jax.block_until_ready(out)
    best = float("inf")
    for _ in range(repeat):
        t = time.perf_counter()
        jax.block_until_ready(fn(*args))
        best = min(best, time.perf_counter() - t)
    return best


def env_steps(name="fourrooms", n_envs=4096, n_steps=1000):
    """vmapped env steps/s of uniformly random actions (one batched draw per step), trajectory kept."""
    env = zsbfm.make_env(name)
    ctx = index_contexts(env.contexts("train"), jnp.arange(n_envs) % num_contexts(env.contexts("train")))

    @jax.jit
    def run(key):
        states = jax.vmap(env.reset)(jax.random.split(key, n_envs), ctx)

        def step(s, k):
            if env.discrete:
                actions = jax.random.randint(k, (n_envs,), 0, env.n_actions)
            else:
                actions = jax.random.uniform(k, (n_envs, env.action_dim), minval=-1, maxval=1)
            s = jax.vmap(env.step)(s, actions)
            return s, s.obs

        return jax.lax.scan(step, states, jax.random.split(key, n_steps))[1]

    return n_envs * n_steps / timed(run, jax.random.PRNGKey(0))


def native_antwind_steps(n_steps=2000):
    """Native MuJoCo (C) env steps/s of the AntWind model, one thread, random actions."""
    import mujoco
    import numpy as np

    from zsbfm.envs.antwind import FRAME_SKIP, TORSO, WIND_FORCE, mj_model

    m = mj_model()
    d = mujoco.MjData(m)
    actions = np.random.default_rng(0).uniform(-1, 1, (n_steps, m.nu))
    t = time.perf_counter()
    for a in actions:
        d.ctrl[:] = a
        d.xfrc_applied[TORSO, :3] = (WIND_FORCE, 0.0, 0.0)
        for _ in range(FRAME_SKIP):
            mujoco.mj_step(m, d)
    return n_steps / (time.perf_counter() - t)


def collection(layouts=20, episodes=500):
    env = zsbfm.make_env("fourrooms", n_train=layouts)
    f = jax.jit(lambda k: collect(env, k, env.contexts("train"), episodes))
    return timed(f, jax.random.PRNGKey(0))


def best_compiled(fn, *args, repeat):
    """Best time of fn(*args) over XLA's default options and zsbfm's (cpu_tuning: YNNPACK
    fusions off): a matmul's rate is the better of the two, whichever the updates use."""
    lowered = jax.jit(fn).lower(*args)
    return min(timed(lowered.compile(compiler_options=opts), *args, repeat=repeat)
               for opts in ({}, compiler_options()))


def matmul_peak(n=2048, repeat=5):
    """Dense float32 matmul GFLOP/s through XLA on this machine, now (n x n by n x n)."""
    a = jax.random.normal(jax.random.PRNGKey(0), (n, n), jnp.float32)
    return 2 * n**3 / best_compiled(lambda x: x @ x, a, repeat=repeat) / 1e9


# The matmul rates a run measures; the peak its fractions divide by is the best of them.
# One 2048^2 measurement alone read anywhere from 69 to 139 GFLOP/s within an hour on the
# same 2-core machine (other tenants): the best of several shapes, measured before and after
# the updates, is the conservative denominator.
PEAK_SHAPES = ((256, 256, 400, "the CPU preset's F output layer, batch 256"),
               (768, 256, 400, "the same, 3 seeds' batches stacked"),
               (1024, 1024, 400, "the paper sizes' F output layer"),
               (1024, 1024, 1024, "square 1024"))


def matmul_rates() -> dict[str, float]:
    """{description: f32 GFLOP/s} for the 2048^2 product and each of PEAK_SHAPES."""
    rates = {"f32 matmul 2048^2 (one product)": matmul_peak()}
    for m, k, n, what in PEAK_SHAPES:
        rates[f"f32 matmul [{m}, {k}] @ [{k}, {n}] and back ({what})"] = matmul_rate(m, k, n)
    return rates


def matmul_rate(m, k, n, repeat=3, iters=200):
    """f32 GFLOP/s of an [m, k] @ [k, n] matmul followed by its [m, n] @ [n, k] partner, in a
    compiled loop of `iters` dependent pairs (nothing to hoist): the rate the small matmuls
    of an update can reach at best, beside the 2048^2 product."""
    ka, kb, kc = jax.random.split(jax.random.PRNGKey(0), 3)
    x = jax.random.normal(ka, (m, k), jnp.float32)
    w1 = jax.random.normal(kb, (k, n), jnp.float32) / k**0.5
    w2 = jax.random.normal(kc, (n, k), jnp.float32) / n**0.5
    f = lambda x: jax.lax.fori_loop(0, iters, lambda _, x: (x @ w1) @ w2, x)
    return 2 * 2 * m * k * n * iters / best_compiled(f, x, repeat=repeat) / 1e9


def timing_config(algo, seeds, steps=200, size="cpu", **overrides):
    """The Four-Rooms preset of `algo` cut into chunks of `steps` updates (its steps and
    encoder steps rounded down to whole chunks), for timing one chunk."""
    cfg = zsbfm.Config.preset("fourrooms", algo, size, num_seeds=seeds, chunk_steps=steps, **overrides)
    if cfg.steps % steps or (algo in ("bfb", "rfb") and cfg.enc_steps % steps):
        cfg = cfg.replace(steps=cfg.steps // steps * steps, enc_steps=max(steps, cfg.enc_steps // steps * steps))
    return cfg


def fb_phase_chunk(cfg, chunk=None, options=None):
    """cfg's training chunk compiled, for timing and profiling: (trainer, carry, dataset,
    compiled, args), where compiled[name](*args) runs chunk `chunk` (default: the last, an
    FB-phase chunk; for belief algos 0 is an encoder-phase chunk) for all of cfg's seeds,
    compiled with each of `options` ({name: XLA options}; default: the options zsbfm.train
    compiles its chunks with, zsbfm/cpu_tuning.py, alone, and `compiled` is that one)."""
    tr = make_train(cfg)
    carry = jax.jit(jax.vmap(tr.init))(seed_keys(cfg))
    ds = jax.jit(jax.vmap(tr.collect_data))(carry)
    args = (carry, ds, jnp.int32(cfg.num_chunks - 1 if chunk is None else chunk), {})
    lowered = jax.jit(jax.vmap(tr.run_chunk, in_axes=(0, 0, None, None))).lower(*args)
    if options is None:
        return tr, carry, ds, lowered.compile(compiler_options=compiler_options()), args
    return tr, carry, ds, {name: lowered.compile(compiler_options=o) for name, o in options.items()}, args


def updates(algo, seeds, steps=200, size="cpu", **overrides):
    """(updates/s over all seeds, GFLOP per update of one seed) of a preset's FB-phase chunk.

    GFLOP per update: XLA's cost analysis of one compiled update (zsbfm.train.update_flops)."""
    from zsbfm.train import update_flops

    cfg = timing_config(algo, seeds, steps, size, **overrides)
    tr, carry, ds, chunk, args = fb_phase_chunk(cfg)
    rate = seeds * steps / timed(lambda: chunk(*args), repeat=3)
    cumulative = update_flops(tr, carry, ds, {})
    return rate, (cumulative(cfg.steps) - cumulative(cfg.steps - 1)) / 1e9  # an FB-phase update


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--quick", action="store_true")
    p.add_argument("--algos", nargs="+", default=["fb", "bfb", "rfb", "oracle", "hilp", "lap"])
    a = p.parse_args()
    print(f"machine: {platform.processor() or platform.machine()}, {jax.device_count()} "
          f"{jax.default_backend()} device(s), jax {jax.__version__}\n")
    print("| measurement | value |\n|---|---|")
    n = 1024 if a.quick else 4096
    print(f"| fourrooms env steps/s ({n} envs x 1000 steps, vmapped) | {env_steps('fourrooms', n):,.0f} |")
    print(f"| collect 1e6 transitions (20 layouts x 500 episodes) | {collection():.3f} s |")
    print(f"| pointmass env steps/s (1024 envs x 250 steps, 5 substeps each) | {env_steps('pointmass', 1024, 250):,.0f} |")
    for n_ant in ((128,) if a.quick else (128, 1024)):
        print(f"| antwind MJX env steps/s ({n_ant} envs x 100 steps, 5 physics steps each) "
              f"| {env_steps('antwind', n_ant, 100):,.0f} |", flush=True)
    print(f"| antwind native MuJoCo env steps/s (1 thread, 5 physics steps each) | {native_antwind_steps():,.0f} |")
    steps = 100 if a.quick else 200
    before = matmul_rates()
    rows = [(algo, "cpu", seeds, {}) for algo in a.algos for seeds in (1, 3)]
    if not a.quick:  # the paper's sizes: a few updates are enough to time them
        rows += [("fb", "paper", 1, {}), ("bfb", "paper", 1, {})]
    measured = []
    for algo, size, seeds, over in rows:
        print(f"timing {algo} {size} x {seeds} seeds...", file=sys.stderr, flush=True)
        measured.append((algo, size, seeds, *updates(algo, seeds, steps if size == "cpu" else 10, size, **over)))
    after = matmul_rates()
    peak = max(*before.values(), *after.values())
    for what in before:
        print(f"| {what}, before / after the updates | {before[what]:,.0f} / {after[what]:,.0f} GFLOP/s |")
    print(f"| f32 matmul peak: the best of the rates above | {peak:,.0f} GFLOP/s |")
    print("\n| update (fourrooms) | seeds | updates/s | GFLOP / update | GFLOP/s | of matmul peak |\n|---|---|---|---|---|---|")
    for algo, size, seeds, rate, gflop in measured:
        print(f"| {algo} {size} preset | {seeds} | {rate:,.{2 if rate < 10 else 1}f} | {gflop:.2f} | {rate * gflop:,.0f} "
              f"| {rate * gflop / peak:.0%} |")


if __name__ == "__main__":
    main()
