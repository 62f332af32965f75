"""The training program.

`make_train(cfg)` returns a `Trainer` of pure, jittable functions; its `train(key)` is the
whole run for one seed (collect data -> `num_chunks` compiled chunks of `chunk_steps`
updates -> evaluate), so `jax.jit(jax.vmap(trainer.train))(keys)` sweeps seeds in one
program. `train(cfg)` is the host driver: it runs the same pieces for all seeds with
`jax.vmap`, one compiled chunk at a time, and between chunks (never inside one) shows
progress, logs metrics and writes an orbax checkpoint, so a killed run resumes from its
last chunk and ends exactly where an uninterrupted run would.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import time
from typing import Any, Callable

import jax
import jax.numpy as jnp
import numpy as np
import orbax.checkpoint as ocp
from flax import struct

from zsbfm.agents import make_agent
from zsbfm.config import Config
from zsbfm.data.collect import collect
from zsbfm.envs import make_env
from zsbfm.evaluate import default_goals, evaluate_params, split_results
from zsbfm.run import Run


@struct.dataclass
class TrainCarry:
    """Everything that changes during training, for one seed."""

    agent_state: Any
    key: jax.Array       # advanced once per chunk
    data_key: jax.Array  # the dataset is a pure function of this key
    chunk: jax.Array     # chunks completed


@dataclasses.dataclass(frozen=True)
class Trainer:
    cfg: Config
    env: Any
    agent: Any
    init: Callable           # key -> TrainCarry
    collect_data: Callable   # TrainCarry -> Dataset
    run_chunk: Callable      # (TrainCarry, Dataset, chunk index) -> (TrainCarry, chunk-mean metrics)
    evaluate: Callable       # TrainCarry -> {"train": bool[n_ctx, n_goals], "test": ...}
    train: Callable          # key -> (TrainCarry, metrics [num_chunks, ...], evaluation)


# Incremented each time a chunk is traced; tests use it to check nothing retraces.
TRACE_COUNTS = {"run_chunk": 0}


def make_train(cfg: Config) -> Trainer:
    env = make_env(cfg.env, n_train=cfg.n_train_layouts, episode_len=cfg.episode_len)
    agent = make_agent(cfg, env)
    train_ctx, test_ctx = env.contexts("train"), env.contexts("test")
    train_goals, test_goals = default_goals(env, train_ctx), default_goals(env, test_ctx)

    def init(key):
        k_data, k_agent, k_loop = jax.random.split(key, 3)
        return TrainCarry(agent_state=agent.init(k_agent), key=k_loop, data_key=k_data,
                          chunk=jnp.zeros((), jnp.int32))

    def collect_data(carry):
        return collect(env, carry.data_key, train_ctx, cfg.episodes_per_layout)

    def run_chunk(carry, dataset, chunk):
        """cfg.chunk_steps updates. `chunk` is the chunk index, shared by all seeds: under
        vmap it stays unbatched, so agents can branch on the global step with a real
        lax.cond (a batched predicate would turn the cond into a select of both branches)."""
        TRACE_COUNTS["run_chunk"] += 1
        key, chunk_key = jax.random.split(carry.key)
        state, metrics = agent.run_steps(carry.agent_state, dataset,
                                         jax.random.split(chunk_key, cfg.chunk_steps),
                                         chunk * cfg.chunk_steps)
        metrics = jax.tree_util.tree_map(jnp.mean, metrics)
        return carry.replace(agent_state=state, key=key, chunk=carry.chunk + 1), metrics

    def evaluate(carry):
        params = agent.eval_params(carry.agent_state)
        k_train, k_test = jax.random.split(jax.random.fold_in(carry.key, 1))
        run = lambda k, ctx, goals: evaluate_params(agent, env, params, k, ctx, goals,
                                                    cfg.eval_episode_len, cfg.context_len)
        return {"train": run(k_train, train_ctx, train_goals), "test": run(k_test, test_ctx, test_goals)}

    def train(key):
        carry = init(key)
        dataset = collect_data(carry)
        carry, metrics = jax.lax.scan(lambda c, i: run_chunk(c, dataset, i), carry,
                                      jnp.arange(cfg.num_chunks, dtype=jnp.int32))
        return carry, metrics, evaluate(carry)

    return Trainer(cfg, env, agent, init, collect_data, run_chunk, evaluate, train)


# --- Host driver ---------------------------------------------------------------------------

def seed_sharding(num_seeds: int, devices=None) -> jax.sharding.NamedSharding:
    """Shard the leading (seed) axis of every leaf over a 1-D mesh ("seeds") of the local
    devices: with D devices, each runs num_seeds / D seeds; with one device this is the
    plain single-device program. num_seeds must be a multiple of D (checked, not padded:
    a padded seed would cost a device's worth of compute for nothing)."""
    devices = jax.local_devices() if devices is None else devices
    if num_seeds % len(devices):
        raise ValueError(f"Config.num_seeds={num_seeds} is invalid: expected a multiple of the "
                         f"{len(devices)} local devices (the seed axis is sharded over devices)")
    mesh = jax.sharding.Mesh(np.asarray(devices), ("seeds",))
    return jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec("seeds"))


def seed_keys(cfg: Config) -> jax.Array:
    """One independent key per seed of the sweep."""
    return jax.random.split(jax.random.PRNGKey(cfg.seed), cfg.num_seeds)


def _checkpoint_manager(run_dir: str) -> ocp.CheckpointManager:
    return ocp.CheckpointManager(os.path.join(run_dir, "checkpoints"),
                                 options=ocp.CheckpointManagerOptions(max_to_keep=2))


def _read_metrics(run_dir: str, upto_chunk: int) -> list[dict]:
    path = os.path.join(run_dir, "metrics.jsonl")
    if not os.path.exists(path):
        return []
    with open(path) as f:
        rows = [json.loads(line) for line in f if line.strip()]
    return [r for r in rows if r["chunk"] <= upto_chunk]


def train(cfg: Config, resume: bool = True, progress: bool = True,
          callback: Callable[[int, dict], None] | None = None) -> Run:
    """Train every seed of `cfg` together (jax.vmap), evaluate, save and return a `Run`.

    resume:   continue from the newest checkpoint in runs/<name>/ if it was written by
              the same config (a different config there is an error, not an overwrite);
              resume=False deletes runs/<name>/ and starts over.
    callback: called on the host after each chunk as callback(chunk, metrics_row).
    """
    run_dir = os.path.abspath(os.path.join(cfg.runs_dir, cfg.run_name))
    cfg_path = os.path.join(run_dir, "config.json")
    if os.path.exists(cfg_path):
        with open(cfg_path) as f:
            old = Config.from_dict(json.load(f))
        if not resume:
            shutil.rmtree(run_dir)
        elif old != cfg:
            diff = {k: (v, getattr(cfg, k)) for k, v in old.to_dict().items() if getattr(cfg, k) != v}
            raise ValueError(f"{run_dir} holds a run with a different config {diff}; choose another "
                             "name (Config.name / --name), or start over (resume=False / --no-resume)")
    os.makedirs(run_dir, exist_ok=True)
    with open(cfg_path, "w") as f:
        f.write(cfg.to_json())

    t0 = time.time()
    trainer = make_train(cfg)
    shard = seed_sharding(cfg.num_seeds)
    carry = jax.jit(jax.vmap(trainer.init), out_shardings=shard)(seed_keys(cfg))
    mngr = _checkpoint_manager(run_dir) if cfg.checkpoint else None
    start = 0
    if mngr is not None and resume and mngr.latest_step() is not None:
        start = mngr.latest_step()
        carry = mngr.restore(start, args=ocp.args.StandardRestore(carry))
    metrics = _read_metrics(run_dir, start)

    # Every seed's data is collected on the device that trains that seed.
    dataset = jax.jit(jax.vmap(trainer.collect_data), out_shardings=shard)(carry)
    chunk_fn = jax.jit(jax.vmap(trainer.run_chunk, in_axes=(0, 0, None)), donate_argnums=0,
                       out_shardings=(shard, shard))
    bar = _progress(cfg, start, progress)
    with open(os.path.join(run_dir, "metrics.jsonl"), "w") as f:
        for row in metrics:
            f.write(json.dumps(row) + "\n")
        for chunk in range(start, cfg.num_chunks):
            t_chunk = time.time()
            carry, m = chunk_fn(carry, dataset, jnp.int32(chunk))
            m = jax.device_get(m)  # the one host transfer per chunk
            row = {"chunk": chunk + 1, "step": (chunk + 1) * cfg.chunk_steps,
                   "seconds": round(time.time() - t_chunk, 3),
                   **{k: np.asarray(v).tolist() for k, v in m.items()}}
            metrics.append(row)
            f.write(json.dumps(row) + "\n")
            f.flush()
            if mngr is not None:
                mngr.save(chunk + 1, args=ocp.args.StandardSave(carry))
            bar.update(1)
            shown = {k: f"{np.mean(row[k]):.3g}" for k in ("fb_loss", "sf_loss", "enc_mse")
                     if k in row and np.isfinite(np.mean(row[k]))}  # the phase's own loss
            bar.set_postfix(shown)
            if callback is not None:
                callback(chunk + 1, row)
    bar.close()
    if mngr is not None:
        mngr.wait_until_finished()
    train_seconds = time.time() - t0

    t_eval = time.time()
    success = jax.jit(jax.vmap(trainer.evaluate))(carry)
    success = jax.device_get(success)
    results = {split: split_results(success[split])["success"] for split in ("train", "test")}
    results["detail"] = {split: split_results(success[split]) for split in ("train", "test")}
    results["wall_time_s"] = {"train": round(train_seconds, 2), "eval": round(time.time() - t_eval, 2)}
    results["resumed_from_chunk"] = start
    params = trainer.agent.eval_params(carry.agent_state)
    run = Run(cfg=cfg, params=params, results=results, metrics=metrics)
    run.save(run_dir)
    try:
        from zsbfm.plots import plot_run

        plot_run(run, run_dir)
    except Exception as e:  # plots must never lose a finished run
        print(f"warning: plotting failed: {e!r}")
    return run


def _progress(cfg: Config, start: int, enabled: bool):
    from tqdm.auto import tqdm

    return tqdm(total=cfg.num_chunks, initial=start, disable=not enabled, unit="chunk",
                desc=f"{cfg.run_name} ({cfg.num_seeds} seeds x {cfg.chunk_steps} steps/chunk)")
