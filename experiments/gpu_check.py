"""Four-Rooms checks for as many updates as fit in a time budget, with their learning curves
and updates/s: the device check of a GPU machine. The default checks: FB and Belief-FB at
the paper's sizes (1 seed; timing), then Belief-FB, Rotation-FB and FB at the authors' code's
settings (size="authors") with 3 vmapped seeds (learning curves; the CPU cannot afford them).

    bash experiments/gpu_check.sh              # GPU: 8 minutes in all
    python experiments/gpu_check.py --budget 60 --tiny   # any machine: tiny sizes
    python experiments/gpu_check.py --checks bfb:authors:3 --budget 400
    python experiments/gpu_check.py --checks bfb:authors:3 --set twin_target=mean --budget 150

On a CPU (no GPU found) it runs the same path at tiny sizes unless --paper is given. Per
check (algo:size:seeds) it compiles one chunk, then trains chunk after chunk until its share
of the budget is spent, evaluating every chunk (official and dense protocols, train and test
layouts) with the program zsbfm.train uses (Trainer.evaluate_protocols, compiled once).
Paper-size belief checks pre-train their encoder for one chunk; authors-size ones for their
preset's enc_steps (tiny: one chunk). --set applies Config overrides (field=value) to every
check. Each row also holds the chunk's mean FB loss terms where its phase has them (M's
diagonal and off-diagonal means, the twin heads' gap E|M1 - M2|). Prints one line per chunk
and a JSON summary; writes it to --out if given.
"""

from __future__ import annotations

import argparse
import json
import time

import jax
import jax.numpy as jnp
import numpy as np

import zsbfm
from zsbfm.train import eval_key, make_train, seed_keys, update_flops

TINY = dict(d=8, f_pre_hidden=(16,), f_pre_out=16, f_hidden=(16,), b_hidden=(16,), batch_size=32,
            n_train_layouts=4, episodes_per_layout=20, enc_embed=16, enc_mlp=16, enc_layers=1,
            pred_hidden=(16,))


DEFAULT_CHECKS = ("fb:paper:1", "bfb:paper:1", "bfb:authors:3", "rfb:authors:3", "fb:authors:3")


def parse_check(text: str) -> tuple[str, str, int]:
    """"algo:size:seeds" -> (algo, size, seeds), with a one-line error for a bad one."""
    parts = text.split(":")
    if len(parts) != 3 or not parts[2].isdigit() or int(parts[2]) < 1:
        raise SystemExit(f"--checks {text!r} is invalid: expected algo:size:seeds, e.g. bfb:authors:3")
    return parts[0], parts[1], int(parts[2])


# chunk metrics reported beside the scores (mean over seeds and the chunk's updates), by phase
FB_LOGGED = ("fb_loss", "M_diag", "M_offdiag", "M_head_gap")
ENC_LOGGED = ("enc_mse",)


def check(algo: str, size: str, seeds: int, budget: float, tiny: bool, chunk: int, overrides=()) -> dict:
    over = dict(TINY) if tiny else {}
    steps = chunk * 1000
    enc = {}
    if algo in ("bfb", "rfb"):  # whole chunks of encoder steps
        preset_enc = zsbfm.Config.preset("fourrooms", algo, size).enc_steps
        enc_steps = chunk if tiny or size != "authors" else max(chunk, preset_enc // chunk * chunk)
        enc = dict(enc_steps=enc_steps)
        steps += enc_steps
    cfg = zsbfm.Config.preset("fourrooms", algo, size, num_seeds=seeds, chunk_steps=chunk, steps=steps,
                              checkpoint=False, **enc, **over).with_overrides(list(overrides))
    t0 = time.time()
    tr = make_train(cfg)
    keys = seed_keys(cfg)
    carry = jax.jit(jax.vmap(tr.init))(keys)
    ds = jax.jit(jax.vmap(tr.collect_data))(carry)
    chunk_fn = jax.jit(jax.vmap(tr.run_chunk, in_axes=(0, 0, None, None)), donate_argnums=0)
    eval_fn = jax.jit(jax.vmap(tr.evaluate_protocols, in_axes=(0, 0, 0, None)))
    ekeys = jax.vmap(eval_key)(keys)
    flops = update_flops(tr, carry, ds, {})
    rows, i = [], 0
    while True:
        t = time.time()
        carry, m = chunk_fn(carry, ds, jnp.int32(i), {})
        jax.block_until_ready(m)
        dt = time.time() - t
        scores = jax.device_get(eval_fn(carry, ds, ekeys, None))
        i += 1
        row = {"updates": i * chunk, "chunk_s": round(dt, 2), "updates_per_s": round(seeds * chunk / dt, 1),
               "gflop_per_update": float(f"{(flops(i * chunk) - flops(i * chunk - 1)) / 1e9:.3g}"),
               **{k: round(float(np.mean(v)), 3) for k, v in scores.items() if k.split("/")[1] in ("paper", "dense")},
               **{k: round(float(np.mean(v)), 3) for k, v in jax.device_get(m).items()
                  if k in (ENC_LOGGED if i * chunk <= cfg.steps - cfg.fb_steps else FB_LOGGED)},
               **{f"{k}_per_seed": np.round(np.asarray(v), 3).tolist() for k, v in scores.items()
                  if k == "train/paper"}}
        rows.append(row)
        print(f"{algo}:{size}:{seeds} {json.dumps(row)}", flush=True)
        if time.time() - t0 > budget or i == cfg.num_chunks:
            break
    return {"algo": algo, "config": size + (" (tiny)" if tiny else ""), "overrides": list(overrides), "seeds": seeds,
            "encoder_steps": cfg.steps - cfg.fb_steps, "wall_s": round(time.time() - t0, 1), "curve": rows}


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--budget", type=float, default=480.0, help="seconds for all algorithms together")
    p.add_argument("--checks", nargs="+", default=list(DEFAULT_CHECKS),
                   help="algo:size:seeds, each given an equal share of the budget")
    p.add_argument("--tiny", action="store_true", help="tiny sizes (default on a CPU)")
    p.add_argument("--paper", action="store_true", help="paper sizes even on a CPU")
    p.add_argument("--chunk", type=int, default=0, help="updates per chunk (default 500 on a GPU, 10 tiny)")
    p.add_argument("--set", nargs="*", default=[], help="Config overrides (field=value) for every check")
    p.add_argument("--out", default="")
    a = p.parse_args()
    backend = jax.default_backend()
    tiny = a.tiny or (backend == "cpu" and not a.paper)
    chunk = a.chunk or (10 if tiny else 500)
    checks = [parse_check(c) for c in a.checks]
    print(f"backend {backend}: {jax.devices()[0].device_kind}; {'tiny' if tiny else 'full'} sizes; "
          f"budget {a.budget:.0f} s; {chunk} updates per chunk", flush=True)
    out = {"backend": backend, "device": jax.devices()[0].device_kind,
           "results": [check(algo, size, seeds, a.budget / len(checks), tiny, chunk, a.set) for algo, size, seeds in checks]}
    print(json.dumps(out))
    if a.out:
        with open(a.out, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
