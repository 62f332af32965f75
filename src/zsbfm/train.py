"""The training program.

`make_train(cfg)` returns a `Trainer` of pure, jittable functions; its `train(key)` is the
whole run for one seed (collect data -> `num_chunks` compiled chunks of `chunk_steps`
updates -> evaluate), so `jax.jit(jax.vmap(trainer.train))(keys)` sweeps seeds in one
program. `train(cfg)` is the host driver: it runs the same pieces for all seeds with
`jax.vmap`, one compiled chunk at a time, and between chunks (never inside one) shows
progress, logs metrics and writes an orbax checkpoint, so a killed run resumes from its
last chunk and ends exactly where an uninterrupted run would. AntWind's host driver reads
one dataset for all seeds from the on-disk cache (zsbfm.data.expert) instead of recording
per seed: MJX rollouts are the costly part there.

Devices (README "Devices"): the host driver places everything on a 2-D mesh
("seeds", "data") of all devices -- every process's in a multi-process run
(`jax.distributed`, see zsbfm.cli) -- built by `seed_sharding`. The seed axis of every
leaf is sharded over "seeds"; Config.data_parallel > 1 also splits each seed's batch
over "data" (the one hook is zsbfm.data.samplers.shard_batch; `chunk_function` traces
the chunk under the mesh so the hook sees it). With one device it is the plain program.
"""

from __future__ import annotations

import dataclasses
import functools
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
from zsbfm.data.samplers import DATA_AXIS
from zsbfm.envs import make_env_for
from zsbfm.evaluate import default_goals, evaluate_params, metric_of, reward_states, split_results
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
    evaluate: Callable       # (TrainCarry, Dataset) -> {"train": scores [n_ctx, n_goals], "test": ...}
    train: Callable          # key -> (TrainCarry, metrics [num_chunks, ...], evaluation)


# Incremented each time a chunk is traced; tests use it to check nothing retraces.
TRACE_COUNTS = {"run_chunk": 0}


def make_train(cfg: Config) -> Trainer:
    env = make_env_for(cfg)  # antwind: with its behaviour expert (trained once, then cached)
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

    def evaluate(carry, dataset):
        params = agent.eval_params(carry.agent_state)
        k_train, k_test, k_states = jax.random.split(jax.random.fold_in(carry.key, 1), 3)
        # metric "return" (antwind): z is inferred from reward-labelled dataset states
        reward_obs = reward_states(k_states, dataset) if metric_of(env) == "return" else None
        run = lambda k, ctx, goals: evaluate_params(agent, env, params, k, ctx, goals,
                                                    cfg.eval_episode_len, cfg.context_len, reward_obs)
        return {"train": run(k_train, train_ctx, train_goals), "test": run(k_test, test_ctx, test_goals)}

    def train(key):
        carry = init(key)
        dataset = collect_data(carry)
        carry, metrics = jax.lax.scan(lambda c, i: run_chunk(c, dataset, i), carry,
                                      jnp.arange(cfg.num_chunks, dtype=jnp.int32))
        return carry, metrics, evaluate(carry, dataset)

    return Trainer(cfg, env, agent, init, collect_data, run_chunk, evaluate, train)


# --- Host driver ---------------------------------------------------------------------------

def seed_sharding(num_seeds: int, devices=None, data_parallel: int = 1) -> jax.sharding.NamedSharding:
    """Shard the leading (seed) axis of every leaf over the "seeds" axis of a 2-D mesh
    ("seeds", "data") of `devices` (default jax.devices(): all processes' devices in a
    multi-process run, the local ones otherwise), shape (D / data_parallel, data_parallel).

    Each "seeds" row trains num_seeds / (D / data_parallel) seeds; leaves are replicated
    over "data" (parameters, optimiser state, the dataset), and only the batch sampled in
    each update is split over it (samplers.shard_batch). Devices are taken in jax.devices()
    order, so a "data" row is consecutive devices: on one host when data_parallel divides
    the local device count. With one device this is the plain single-device program.
    Divisibility is checked here, before anything compiles (no padding: a padded seed
    would cost a device's worth of compute for nothing)."""
    devices = jax.devices() if devices is None else devices
    n = len(devices)
    if n % data_parallel:
        raise ValueError(f"Config.data_parallel={data_parallel} is invalid: expected a divisor of the "
                         f"{n} devices (the mesh is (devices / data_parallel) seeds x data_parallel)")
    n_seeds_axis = n // data_parallel
    if num_seeds % n_seeds_axis:
        raise ValueError(f"Config.num_seeds={num_seeds} is invalid: expected a multiple of the "
                         f"{n_seeds_axis} devices of the 'seeds' mesh axis ({n} devices / data_parallel="
                         f"{data_parallel}; the seed axis is sharded over devices)")
    mesh = jax.sharding.Mesh(np.asarray(devices).reshape(n_seeds_axis, data_parallel), ("seeds", DATA_AXIS))
    return jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec("seeds"))


def replicated(shard: jax.sharding.NamedSharding) -> jax.sharding.NamedSharding:
    """Every device of shard's mesh holds the whole array (small outputs every process reads)."""
    return jax.sharding.NamedSharding(shard.mesh, jax.sharding.PartitionSpec())


def on_mesh(fn: Callable, mesh: jax.sharding.Mesh) -> Callable:
    """fn traced with `mesh` as the context (abstract) mesh, so that the data-parallel hook
    (samplers.shard_batch) sees its "data" axis; wrap a function before jax.jit."""
    @functools.wraps(fn)  # keeps fn's name for the compiled module (jit_run_chunk)
    def traced_on_mesh(*args):
        with jax.sharding.use_abstract_mesh(mesh.abstract_mesh):
            return fn(*args)
    return traced_on_mesh


def chunk_function(trainer: Trainer, shard: jax.sharding.NamedSharding) -> Callable:
    """The compiled chunk zsbfm.train runs: (carry, dataset, np.int32 chunk) -> (carry, metrics).

    vmap over seeds with spmd_axis_name="seeds", so the batch constraint inside becomes
    P("seeds", "data") rather than replicating the seed axis; carry donated and kept on
    `shard`; the chunk-mean metrics replicated (tiny; every process can read them)."""
    per_seed = jax.vmap(trainer.run_chunk, in_axes=(0, 0, None), spmd_axis_name="seeds")
    return jax.jit(on_mesh(per_seed, shard.mesh), donate_argnums=0, out_shardings=(shard, replicated(shard)))


def global_array(x, shard: jax.sharding.NamedSharding) -> jax.Array:
    """A host array (the same on every process) placed on `shard`; each process supplies
    its own devices' pieces (works with one process or many)."""
    x = np.asarray(x)
    return jax.make_array_from_callback(x.shape, shard, lambda idx: x[idx])


def _barrier(name: str) -> None:
    """Wait for every process (multi-process runs); nothing with one process."""
    if jax.process_count() > 1:
        from jax.experimental import multihost_utils

        multihost_utils.sync_global_devices(name)


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
              the same config (a different config there is an error, not an overwrite;
              data_parallel may differ: it is placement), on any number of devices;
              resume=False deletes runs/<name>/ and starts over.
    callback: called on the host after each chunk as callback(chunk, metrics_row).

    Multi-process (after jax.distributed.initialize; zsbfm.cli does it): every process
    calls this with the same cfg; runs_dir must be on a filesystem all processes share.
    Each process collects and trains its own devices' seeds; orbax writes the checkpoints
    together; process 0 alone writes config.json, metrics.jsonl, results.json and plots;
    the returned Run's params are replicated on every process.
    """
    run_dir = os.path.abspath(os.path.join(cfg.runs_dir, cfg.run_name))
    cfg_path = os.path.join(run_dir, "config.json")
    primary = jax.process_index() == 0  # writes the run's files (multi-process runs)
    if os.path.exists(cfg_path):
        with open(cfg_path) as f:  # data_parallel is placement: a run may resume with another
            old = dataclasses.replace(Config.from_dict(json.load(f)), data_parallel=cfg.data_parallel)
        if not resume:
            _barrier("zsbfm: config read")
            if primary:
                shutil.rmtree(run_dir)
        elif old != cfg:
            diff = {k: (v, getattr(cfg, k)) for k, v in old.to_dict().items() if getattr(cfg, k) != v}
            raise ValueError(f"{run_dir} holds a run with a different config {diff}; choose another "
                             "name (Config.name / --name), or start over (resume=False / --no-resume)")
    os.makedirs(run_dir, exist_ok=True)
    if primary:
        with open(cfg_path, "w") as f:
            f.write(cfg.to_json())
    _barrier("zsbfm: run directory ready")

    t0 = time.time()
    trainer = make_train(cfg)
    shard = seed_sharding(cfg.num_seeds, data_parallel=cfg.data_parallel)
    carry = jax.jit(jax.vmap(trainer.init), out_shardings=shard)(global_array(seed_keys(cfg), shard))
    mngr = _checkpoint_manager(run_dir) if cfg.checkpoint else None
    start = 0
    if mngr is not None and resume and mngr.latest_step() is not None:
        start = mngr.latest_step()
        carry = mngr.restore(start, args=ocp.args.StandardRestore(carry))
    metrics = _read_metrics(run_dir, start)

    if cfg.env == "antwind":
        # One dataset for every seed, read from the on-disk cache (`make data ENV=antwind`)
        # or recorded once and cached: MJX rollouts are too costly to redo per seed here.
        from zsbfm.data.expert import load_or_collect_dataset

        ds = load_or_collect_dataset(cfg, trainer.env, progress and primary)
        dataset = jax.tree_util.tree_map(
            lambda x: global_array(np.broadcast_to(np.asarray(x), (cfg.num_seeds,) + x.shape), shard), ds)
    else:  # every seed's data is collected on the device that trains that seed
        dataset = jax.jit(jax.vmap(trainer.collect_data), out_shardings=shard)(carry)
    chunk_fn = chunk_function(trainer, shard)
    bar = _progress(cfg, start, progress and primary)
    with open(os.path.join(run_dir, "metrics.jsonl") if primary else os.devnull, "w") as f:
        for row in metrics:
            f.write(json.dumps(row) + "\n")
        for chunk in range(start, cfg.num_chunks):
            t_chunk = time.time()
            carry, m = chunk_fn(carry, dataset, np.int32(chunk))
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
    success = jax.jit(jax.vmap(trainer.evaluate), out_shardings=replicated(shard))(carry, dataset)
    success = jax.device_get(success)
    results = {split: split_results(success[split])["success"] for split in ("train", "test")}
    results["detail"] = {split: split_results(success[split]) for split in ("train", "test")}
    results["wall_time_s"] = {"train": round(train_seconds, 2), "eval": round(time.time() - t_eval, 2)}
    results["resumed_from_chunk"] = start
    results["metric"] = metric_of(trainer.env)
    params = trainer.agent.eval_params(carry.agent_state)
    if jax.process_count() > 1:  # each process holds only its seeds: gather them everywhere
        params = jax.jit(lambda p: p, out_shardings=replicated(shard))(params)
    run = Run(cfg=cfg, params=params, results=results, metrics=metrics)
    run.save(run_dir)
    if not primary:
        return run
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
