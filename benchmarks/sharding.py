"""Seed-sharded training chunks: updates/s on 1 and 2 (forced host) devices.

    python benchmarks/sharding.py

Each measurement runs in its own process (the device count is fixed at JAX start-up):
the fourrooms FB CPU preset, 2 vmapped seeds, one 200-step chunk after a warm-up, best of 3;
"unsharded" is the plain jit(vmap) chunk, "sharded" the one zsbfm.train uses.
"""
import json
import os
import subprocess
import sys

CHILD = r"""
import os, sys, json, time
os.environ["XLA_FLAGS"] = "--xla_force_host_platform_device_count=%d"
os.environ["JAX_PLATFORMS"] = "cpu"
import jax, jax.numpy as jnp, zsbfm
from zsbfm.train import make_train, seed_keys, seed_sharding
cfg = zsbfm.Config.preset("fourrooms", "fb", num_seeds=2, chunk_steps=200)
tr = make_train(cfg)
out = {}
for mode in ("unsharded", "sharded"):
    shard = seed_sharding(2) if mode == "sharded" else None
    kw = {} if shard is None else {"out_shardings": shard}
    carry = jax.jit(jax.vmap(tr.init), **kw)(seed_keys(cfg))
    ds = jax.jit(jax.vmap(tr.collect_data), **kw)(carry)
    kw2 = {} if shard is None else {"out_shardings": (shard, shard)}
    f = jax.jit(jax.vmap(tr.run_chunk, in_axes=(0, 0, None)), **kw2)
    jax.block_until_ready(f(carry, ds, jnp.int32(0)))
    best = 1e9
    for _ in range(3):
        t = time.perf_counter(); jax.block_until_ready(f(carry, ds, jnp.int32(0))); best = min(best, time.perf_counter() - t)
    out[mode] = 2 * 200 / best
print(json.dumps(out))
"""


def main():
    print("| devices | unsharded seed-updates/s | sharded seed-updates/s |\n|---|---|---|")
    for d in (1, 2):
        r = subprocess.run([sys.executable, "-c", CHILD % d], capture_output=True, text=True, check=True)
        res = json.loads(r.stdout.strip().splitlines()[-1])
        print(f"| {d} | {res['unsharded']:.0f} | {res['sharded']:.0f} |", flush=True)


if __name__ == "__main__":
    main()
