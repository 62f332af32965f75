"""Sharded training chunks: updates/s on 1 and 2 (forced host) devices.

    python benchmarks/sharding.py                      # seeds sharded over devices
    python benchmarks/sharding.py --data-parallel      # + each seed's batch split over devices
    python benchmarks/sharding.py --data-parallel --seeds 1 --batch-size 1024

Each measurement runs in its own process (the device count is fixed at JAX start-up):
the fourrooms FB CPU preset, `--seeds` vmapped seeds (default 2), one 200-step chunk after
a warm-up, best of `--repeats` (default 3), the modes interleaved. "unsharded" is the
plain jit(vmap) chunk; "sharded" is the chunk zsbfm.train runs (train.chunk_function) with the seeds over the
devices (data_parallel=1); "data-parallel" is the same with data_parallel = devices (mesh
1 x devices: every seed's batch split over all devices).
"""
import argparse
import json
import os
import subprocess
import sys

CHILD = r"""
import os, sys, json, time
os.environ["XLA_FLAGS"] = "--xla_force_host_platform_device_count=%(devices)d"
os.environ["JAX_PLATFORMS"] = "cpu"
import numpy as np, jax, jax.numpy as jnp, zsbfm
from zsbfm.train import chunk_function, global_array, make_train, seed_keys, seed_sharding
S, D = %(seeds)d, %(devices)d
modes = ["unsharded", "sharded"] + (["data-parallel"] if %(data_parallel)s else [])
fns = {}
for mode in modes:
    dp = D if mode == "data-parallel" else 1
    cfg = zsbfm.Config.preset("fourrooms", "fb", num_seeds=S, chunk_steps=200, batch_size=%(batch_size)d, data_parallel=dp)
    tr = make_train(cfg)
    if mode == "unsharded":
        carry = jax.jit(jax.vmap(tr.init))(seed_keys(cfg))
        ds = jax.jit(jax.vmap(tr.collect_data))(carry)
        f = jax.jit(jax.vmap(tr.run_chunk, in_axes=(0, 0, None)))
        fresh = lambda carry=carry: carry
    else:
        if S %% (D // dp):
            continue
        shard = seed_sharding(S, data_parallel=dp)
        carry = jax.jit(jax.vmap(tr.init), out_shardings=shard)(global_array(seed_keys(cfg), shard))
        ds = jax.jit(jax.vmap(tr.collect_data), out_shardings=shard)(carry)
        f = chunk_function(tr, shard)
        # chunk_function donates the carry: give each call a fresh copy (not timed)
        copy = jax.jit(lambda c: jax.tree_util.tree_map(jnp.copy, c), out_shardings=shard)
        fresh = lambda carry=carry, copy=copy: jax.block_until_ready(copy(carry))
    jax.block_until_ready(f(fresh(), ds, np.int32(0)))  # compile + warm up
    fns[mode] = (f, ds, fresh)
# interleaved (mode after mode, best of the repeats): load from other processes hits all modes alike
best = {mode: 1e9 for mode in fns}
for _ in range(%(repeats)d):
    for mode, (f, ds, fresh) in fns.items():
        c = fresh()
        t = time.perf_counter(); jax.block_until_ready(f(c, ds, np.int32(0))); best[mode] = min(best[mode], time.perf_counter() - t)
out = {mode: S * 200 / b for mode, b in best.items()}
print(json.dumps(out))
"""


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data-parallel", action="store_true", help="also measure data_parallel = devices")
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--batch-size", type=int, default=256)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--devices", type=int, nargs="+", default=[1, 2])
    a = ap.parse_args()
    cols = ["unsharded", "sharded"] + (["data-parallel"] if a.data_parallel else [])
    print(f"{a.seeds} seeds, batch {a.batch_size}, seed-updates/s (best of {a.repeats})\n")
    print("| devices | " + " | ".join(cols) + " |\n|---|" + "---|" * len(cols))
    for d in a.devices:
        child = CHILD % dict(devices=d, seeds=a.seeds, batch_size=a.batch_size, repeats=a.repeats,
                             data_parallel=a.data_parallel)
        r = subprocess.run([sys.executable, "-c", child], capture_output=True, text=True)
        if r.returncode:
            sys.exit(r.stderr[-3000:])
        res = json.loads(r.stdout.strip().splitlines()[-1])
        print(f"| {d} | " + " | ".join(f"{res[c]:.3g}" if c in res else "-" for c in cols) + " |", flush=True)


if __name__ == "__main__":
    main()
