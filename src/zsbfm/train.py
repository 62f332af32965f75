"""The training program.

`make_train(cfg)` returns a `Trainer` of pure, jittable functions; its `train(key)` is the
whole run for one seed (collect data -> `num_chunks` compiled chunks of `chunk_steps`
updates -> evaluate), so `jax.jit(jax.vmap(trainer.train))(keys)` sweeps seeds in one
program. `train(cfg)` is the host driver: it runs the same pieces for all seeds with
`jax.vmap`, one compiled chunk at a time, and between chunks (never inside one) shows
progress, logs metrics and writes an orbax checkpoint, so a killed run resumes from its
last chunk and ends exactly where an uninterrupted run would. The data comes from
zsbfm.data.sources: collected per seed on device, or one dataset shared by every seed
(a saved .npz, Config.dataset; AntWind's cached expert data).

Devices (README "Devices"): the host driver places everything on a 2-D mesh
("seeds", "data") of all devices -- every process's in a multi-process run
(`jax.distributed`, see zsbfm.cli) -- built by `seed_sharding`. The seed axis of every
leaf is sharded over "seeds"; Config.data_parallel > 1 also splits each seed's batch
over "data" (the one hook is zsbfm.data.samplers.shard_batch; `chunk_function` traces
the chunk under the mesh so the hook sees it). With one device it is the plain program.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import json
import os
import shutil
import sys
import time
from typing import Any, Callable

import jax
import jax.numpy as jnp
import numpy as np
import orbax.checkpoint as ocp
from flax import struct

from zsbfm.agents import make_agent
from zsbfm.agents.base import chunk_metrics
from zsbfm.config import Config
from zsbfm.cpu_tuning import compiler_options
from zsbfm.data.collect import collect
from zsbfm.data.samplers import DATA_AXIS
from zsbfm.data.sources import shared_dataset
from zsbfm.data.sources import make_env_for
from zsbfm.encoder_reuse import encoder_checkpoint, seed_from_encoder_run
from zsbfm.evaluate import (default_goals, evaluate_params, evaluate_protocol, metric_of, protocol_score,
                            protocols_of, reward_states, split_results)
from zsbfm.interrupt import StopSignals
from zsbfm.keys import eval_key, seed_keys  # noqa: F401  (zsbfm.train.seed_keys: the seeds' keys)
from zsbfm.lock import LOCK_NAME, RunDirLock
from zsbfm.nonfinite import NonFiniteError, all_finite, describe, keep_finite
from zsbfm.run import Run, jsonable, read_metrics, write_text


@struct.dataclass
class TrainCarry:
    """Everything that changes during training, for one seed."""

    agent_state: Any
    key: jax.Array       # advanced once per chunk
    data_key: jax.Array  # the dataset is a pure function of this key
    chunk: jax.Array     # chunks completed


@dataclasses.dataclass(frozen=True)
class Trainer:
    """The pure pieces of a run. `hp` (every piece's last argument, default None) holds
    traced values of the scalar settings a vmapped sweep varies (`Config.SWEEPABLE`):
    {field: float32[]} per seed row; None or {} trains cfg's own values."""

    cfg: Config
    env: Any
    agent: Any
    init: Callable           # key -> TrainCarry
    collect_data: Callable   # TrainCarry -> Dataset (the shared dataset, or collected from the carry's data key)
    shared: Any              # the Dataset every seed shares (zsbfm.data.sources), or None
    run_chunk: Callable      # (TrainCarry, Dataset, chunk index, hp) -> (TrainCarry, chunk-mean metrics + "finite")
    evaluate: Callable       # (TrainCarry, Dataset, eval key, hp) -> {"train": scores [n_ctx, n_goals], "test": ...}
    evaluate_protocols: Callable  # (TrainCarry, Dataset, eval key, hp) -> {"<split>/<protocol>": score}
    train: Callable          # key -> (TrainCarry, metrics [num_chunks, ...], evaluation)
    agent_for: Callable      # hp -> the agent with those settings


# Incremented each time a chunk is traced; tests use it to check nothing retraces.
TRACE_COUNTS = {"run_chunk": 0, "evaluate_protocols": 0}


def run_protocols(cfg: Config, env) -> tuple[str, ...]:
    """The protocols a run of cfg scores, the official one first: all of the env's
    (eval_protocols="all") or the official one alone."""
    return protocols_of(env) if cfg.eval_protocols == "all" else protocols_of(env)[:1]


def make_train(cfg: Config, progress: bool = False) -> Trainer:
    env = make_env_for(cfg)  # antwind: with its behaviour expert (trained once, then cached)
    agent = make_agent(cfg, env)
    shared = shared_dataset(cfg, env, progress)
    train_ctx, test_ctx = env.contexts("train"), env.contexts("test")
    train_goals, test_goals = default_goals(env, train_ctx), default_goals(env, test_ctx)
    protocols = run_protocols(cfg, env)

    def agent_for(hp):
        return agent if not hp else make_agent(cfg.with_traced(hp), env)

    def init(key):
        k_data, k_agent, k_loop = jax.random.split(key, 3)
        return TrainCarry(agent_state=agent.init(k_agent), key=k_loop, data_key=k_data,
                          chunk=jnp.zeros((), jnp.int32))

    def collect_data(carry):
        if shared is not None:
            return jax.tree_util.tree_map(jnp.asarray, shared)
        return collect(env, carry.data_key, train_ctx, cfg.episodes_per_layout)

    def run_chunk(carry, dataset, chunk, hp=None):
        """cfg.chunk_steps updates. `chunk` is the chunk index, shared by all seeds: under
        vmap it stays unbatched, so agents can branch on the global step with a real
        lax.cond (a batched predicate would turn the cond into a select of both branches).

        The metrics are the chunk means, plus "finite": whether they and the whole agent
        state are finite (zsbfm.nonfinite); a chunk that was not keeps the state it started
        from, so a non-finite state never reaches a checkpoint."""
        TRACE_COUNTS["run_chunk"] += 1
        key, chunk_key = jax.random.split(carry.key)
        state, metrics = agent_for(hp).run_steps(carry.agent_state, dataset,
                                                 jax.random.split(chunk_key, cfg.chunk_steps),
                                                 chunk * cfg.chunk_steps)
        metrics = jax.tree_util.tree_map(jnp.mean, metrics)
        finite = all_finite((metrics, state))
        state = keep_finite(finite, state, carry.agent_state)
        return carry.replace(agent_state=state, key=key, chunk=carry.chunk + 1), {**metrics, "finite": finite}

    def split_keys(key, dataset):
        k_train, k_test, k_states = jax.random.split(key, 3)
        # metric "return" (antwind): z is inferred from reward-labelled dataset states
        reward_obs = reward_states(k_states, dataset) if metric_of(env) == "return" else None
        return k_train, k_test, reward_obs

    def evaluate(carry, dataset, key, hp=None):
        """The official scores: {"train": [n_ctx, n_goals], "test": ...}."""
        a = agent_for(hp)
        params = a.eval_params(carry.agent_state)
        k_train, k_test, reward_obs = split_keys(key, dataset)
        run = lambda k, ctx, goals: evaluate_params(a, env, params, k, ctx, goals,
                                                    cfg.eval_episode_len, cfg.context_len, reward_obs,
                                                    cfg.context_episodes)
        return {"train": run(k_train, train_ctx, train_goals), "test": run(k_test, test_ctx, test_goals)}

    def evaluate_protocols(carry, dataset, key, hp=None, skip_official=False):
        """Every protocol's mean score on both splits: {"train/paper": float32[], ...}.
        The official protocol's score is the mean of `evaluate`'s (same keys, same tasks);
        skip_official leaves it out (for a caller that has `evaluate`'s scores already)."""
        TRACE_COUNTS["evaluate_protocols"] += 1
        a = agent_for(hp)
        params = a.eval_params(carry.agent_state)
        k_train, k_test, reward_obs = split_keys(key, dataset)
        out = {}
        for split, k, ctx in (("train", k_train, train_ctx), ("test", k_test, test_ctx)):
            for protocol in protocols[1:] if skip_official else protocols:
                score, valid = evaluate_protocol(a, env, params, k, ctx, protocol, cfg.eval_episode_len,
                                                 cfg.context_len, reward_obs, cfg.context_episodes)
                out[f"{split}/{protocol}"] = protocol_score(score, valid)
        return out

    def train(key):
        carry = init(key)
        dataset = collect_data(carry)
        carry, metrics = jax.lax.scan(lambda c, i: run_chunk(c, dataset, i), carry,
                                      jnp.arange(cfg.num_chunks, dtype=jnp.int32))
        return carry, metrics, evaluate(carry, dataset, eval_key(key))

    return Trainer(cfg, env, agent, init, collect_data, shared, run_chunk, evaluate, evaluate_protocols,
                   train, agent_for)


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
    """The compiled chunk zsbfm.train runs: (carry, dataset, np.int32 chunk, hp) -> (carry, metrics).

    vmap over seeds (rows: setting x seed in a sweep) with spmd_axis_name="seeds", so the
    batch constraint inside becomes P("seeds", "data") rather than replicating the seed
    axis; carry donated and kept on `shard`; the chunk-mean metrics replicated (tiny; every
    process can read them). hp: {field: float32[rows]} ({} for a plain run)."""
    per_seed = jax.vmap(trainer.run_chunk, in_axes=(0, 0, None, 0), spmd_axis_name="seeds")
    return jax.jit(on_mesh(per_seed, shard.mesh), donate_argnums=0, out_shardings=(shard, replicated(shard)),
                   compiler_options=compiler_options())


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


def _checkpoint_manager(run_dir: str) -> ocp.CheckpointManager:
    return ocp.CheckpointManager(os.path.join(run_dir, "checkpoints"),
                                 options=ocp.CheckpointManagerOptions(max_to_keep=2))


def update_flops(trainer: Trainer, carry, dataset, hp) -> Callable[[int], float]:
    """Cumulative FLOPs of one seed row after `step` updates, from XLA's cost analysis of
    one compiled update of the same program (compiled here; nothing runs): updates before
    cfg.steps - cfg.fb_steps (a staged belief run's encoder phase) cost what the first
    update costs, later ones what the last one costs."""
    cfg = trainer.cfg
    row = jax.tree_util.tree_map(lambda x: x[0], (carry, dataset, hp))

    def cost_at(first_step):
        def one_update(c, ds, h):
            return trainer.agent_for(h).run_steps(c.agent_state, ds, c.key[None], jnp.int32(first_step))

        cost = jax.jit(one_update, compiler_options=compiler_options()).lower(*row).compile().cost_analysis()
        cost = cost[0] if isinstance(cost, (list, tuple)) else cost
        return float(cost.get("flops", float("nan")))

    switch = cfg.steps - cfg.fb_steps
    late = cost_at(cfg.steps - 1)
    early = cost_at(0) if switch else late
    return lambda step: early * min(step, switch) + late * max(0, step - switch)


def prepare_run_dir(cfg: Config, resume: bool, extra: dict | None = None) -> str:
    """runs/<name>/ with config.json (and `extra`, e.g. a sweep's grid, beside it): a
    different config already there is an error; resume=False starts over."""
    run_dir = os.path.abspath(os.path.join(cfg.runs_dir, cfg.run_name))
    cfg_path = os.path.join(run_dir, "config.json")
    primary = jax.process_index() == 0  # writes the run's files (multi-process runs)
    if os.path.exists(cfg_path):
        with open(cfg_path) as f:  # placement and policy: a run may resume with other values
            old = dataclasses.replace(Config.from_dict(json.load(f)), data_parallel=cfg.data_parallel,
                                      on_nonfinite=cfg.on_nonfinite)
        old_extra = None
        if os.path.exists(os.path.join(run_dir, "sweep.json")):
            with open(os.path.join(run_dir, "sweep.json")) as f:
                old_extra = json.load(f).get("grid")
        if not resume:
            _barrier("zsbfm: config read")
            if primary:  # everything but the lock this run holds (zsbfm.lock)
                for entry in os.listdir(run_dir):
                    path = os.path.join(run_dir, entry)
                    if entry != LOCK_NAME:
                        shutil.rmtree(path) if os.path.isdir(path) else os.remove(path)
        elif old != cfg or (extra or {}).get("grid") != old_extra:
            diff = {k: (v, getattr(cfg, k)) for k, v in old.to_dict().items() if getattr(cfg, k) != v}
            if (extra or {}).get("grid") != old_extra:
                diff["sweep grid"] = (old_extra, (extra or {}).get("grid"))
            raise ValueError(f"{run_dir} holds a run with a different config {diff}; choose another "
                             "name (Config.name / --name), or start over (resume=False / --no-resume)")
    os.makedirs(run_dir, exist_ok=True)
    if primary:
        write_text(cfg_path, cfg.to_json())
        if extra is not None:
            with open(os.path.join(run_dir, "sweep.json"), "w") as f:
                json.dump(extra, f, indent=2)
    _barrier("zsbfm: run directory ready")
    return run_dir


@dataclasses.dataclass
class LoopResult:
    """What `run_loop` leaves: the final carry (rows on `shard`), the dataset, every chunk's
    metrics row, the chunk it resumed from, the training wall time of this call, and the
    rows dropped for going non-finite ({row: chunk}, Config.on_nonfinite="drop")."""

    carry: Any
    dataset: Any
    metrics: list
    start: int
    train_seconds: float
    shard: Any
    eval_fn: Callable
    keys: jax.Array
    hp: dict
    dropped: dict = dataclasses.field(default_factory=dict)


def _blank_rows(row: dict, rows: int, blank) -> dict:
    """row with the entries of the rows in `blank` set to None in every per-row list."""
    return {k: [None if i in blank else x for i, x in enumerate(v)] if isinstance(v, list) and len(v) == rows
            else v for k, v in row.items()}


def run_loop(trainer: Trainer, run_dir: str, keys, hp: dict, resume: bool, progress: bool,
             callback: Callable[[int, dict], None] | None = None, label: str = "",
             stop: StopSignals | None = None, row_name: Callable[[int], str] | None = None) -> LoopResult:
    """Train the rows of `keys` (one seed key per row) with their settings `hp` ({field:
    [rows]}, {} for cfg's own), one compiled chunk at a time, resuming from run_dir's newest
    checkpoint. Between chunks: metrics.jsonl, a checkpoint, progress, callback(chunk, row),
    and every cfg.eval_every chunks a learning-curve evaluation (`Trainer.evaluate_protocols`,
    compiled once) logged as "eval/<split>/<protocol>" with the update count, wall time and
    cumulative FLOPs (`update_flops` x updates).

    A metrics row holds the metrics the chunk's phase computed (`chunk_metrics`), one value
    per row, strict JSON (no NaN). A row whose chunk went non-finite is handled by
    cfg.on_nonfinite (zsbfm.nonfinite): "stop" raises NonFiniteError before anything of
    that chunk is written; "drop" lists it under "dropped" and blanks its values (None)
    from then on. `stop` defers SIGINT / SIGTERM to the next chunk boundary (zsbfm.interrupt;
    default: its own for the loop). row_name(i) names row i in messages ("seed i")."""
    cfg = trainer.cfg
    rows = int(np.asarray(keys).shape[0])
    row_name = row_name or (lambda i: f"seed {i}")
    primary = jax.process_index() == 0
    t0 = time.time()
    shard = seed_sharding(rows, data_parallel=cfg.data_parallel)
    carry = jax.jit(jax.vmap(trainer.init), out_shardings=shard)(global_array(keys, shard))
    hp = {k: global_array(np.asarray(v, np.float32), shard) for k, v in hp.items()}
    mngr = _checkpoint_manager(run_dir) if cfg.checkpoint else None
    start = 0
    if mngr is not None and resume and mngr.latest_step() is not None:
        start = mngr.latest_step()
        carry = mngr.restore(start, args=ocp.args.StandardRestore(carry))
    metrics = read_metrics(run_dir, start)
    elapsed0 = metrics[-1].get("wall_s", 0.0) if metrics else 0.0
    dropped: dict[int, int] = {}  # row -> the chunk it was dropped at, read back on resume
    for r in metrics:
        for i in r.get("dropped", []):
            dropped.setdefault(i, r["chunk"])

    if trainer.shared is not None:  # one dataset for every row (zsbfm.data.sources)
        dataset = jax.tree_util.tree_map(
            lambda x: global_array(np.broadcast_to(np.asarray(x), (rows,) + x.shape), shard), trainer.shared)
    else:  # every seed's data is collected on the device that trains that seed
        dataset = jax.jit(jax.vmap(trainer.collect_data), out_shardings=shard)(carry)
    chunk_fn = chunk_function(trainer, shard)
    ekeys = global_array(np.asarray(jax.vmap(eval_key)(jnp.asarray(keys))), shard)
    eval_fn = jax.jit(jax.vmap(trainer.evaluate_protocols), out_shardings=replicated(shard))
    flops = update_flops(trainer, carry, dataset, hp) if cfg.eval_every else None
    bar = _progress(cfg, start, progress and primary, label)
    t_loop = time.time()
    with contextlib.ExitStack() as cleanup:
        stop = stop or cleanup.enter_context(StopSignals())
        cleanup.callback(bar.close)
        if mngr is not None:  # also on the way out of an error: the last save completes
            cleanup.callback(mngr.wait_until_finished)
        f = cleanup.enter_context(open(os.path.join(run_dir, "metrics.jsonl") if primary else os.devnull, "w"))
        for row in metrics:
            f.write(json.dumps(jsonable(row), allow_nan=False) + "\n")
        for chunk in range(start, cfg.num_chunks):
            stop.check(chunk, cfg.num_chunks)
            t_chunk = time.time()
            carry, m = chunk_fn(carry, dataset, np.int32(chunk), hp)
            m = jax.device_get(m)  # the one host transfer per chunk
            finite = np.asarray(m.pop("finite"), bool).reshape(rows)
            names = chunk_metrics(trainer.agent, chunk * cfg.chunk_steps, m)
            step = (chunk + 1) * cfg.chunk_steps
            row = {"chunk": chunk + 1, "step": step, "seconds": round(time.time() - t_chunk, 3),
                   **{k: np.asarray(m[k]).reshape(rows).tolist() for k in names}}
            bad = [i for i in np.flatnonzero(~finite).tolist() if i not in dropped]
            if bad:
                where = f"chunk {chunk + 1}/{cfg.num_chunks} (updates {chunk * cfg.chunk_steps + 1}-{step})"
                what = describe(row, names, bad, metrics, row_name)
                if cfg.on_nonfinite == "stop" or len(dropped) + len(bad) == rows:
                    last = mngr.latest_step() if mngr is not None else None
                    kept = f"the checkpoint of chunk {last} is kept" if last else "no checkpoint was written"
                    hint = ("; to finish the other seeds, run again with --set on_nonfinite=drop"
                            if cfg.on_nonfinite == "stop" and len(dropped) + len(bad) < rows
                            else "; no seed is left to train" if cfg.on_nonfinite == "drop" else "")
                    raise NonFiniteError(f"non-finite training in {where}: {what}; {kept}{hint}", bad, chunk + 1)
                print(f"warning: dropped in {where}: {what}", file=sys.stderr)
                dropped.update({i: chunk + 1 for i in bad})
            if cfg.eval_every and ((chunk + 1) % cfg.eval_every == 0 or chunk + 1 == cfg.num_chunks):
                scores = jax.device_get(eval_fn(carry, dataset, ekeys, hp))
                row.update({f"eval/{k}": np.round(np.asarray(v), 4).tolist() for k, v in scores.items()})
                row["flops"] = flops(step)
            row["wall_s"] = round(elapsed0 + time.time() - t_loop, 2)
            if dropped:
                row = dict(_blank_rows(row, rows, dropped), dropped=sorted(dropped))
            row = jsonable(row)
            metrics.append(row)
            f.write(json.dumps(row, allow_nan=False) + "\n")
            f.flush()
            if mngr is not None:
                mngr.save(chunk + 1, args=ocp.args.StandardSave(carry))
            bar.update(1)
            shown = {k: f"{np.mean([x for x in row[k] if x is not None]):.3g}"
                     for k in ("fb_loss", "sf_loss", "enc_mse") if k in row and len(dropped) < rows}
            shown.update({k[5:]: f"{np.mean([x for x in row[k] if x is not None]):.2f}"
                          for k in row if k.startswith("eval/") and k.endswith("/dense")})
            bar.set_postfix(shown)
            if callback is not None:
                callback(chunk + 1, row)
        stop.check(cfg.num_chunks, cfg.num_chunks)
    return LoopResult(carry, dataset, metrics, start, time.time() - t0, shard, eval_fn, ekeys, hp, dropped)


def train(cfg: Config, resume: bool = True, progress: bool = True,
          callback: Callable[[int, dict], None] | None = None, encoder_from: str = "") -> Run:
    """Train every seed of `cfg` together (jax.vmap), evaluate, save and return a `Run`.

    resume:   continue from the newest checkpoint in runs/<name>/ if it was written by
              the same config (a different config there is an error, not an overwrite;
              data_parallel and on_nonfinite may differ), on any number of devices;
              resume=False deletes runs/<name>/ and starts over.
    callback: called on the host after each chunk as callback(chunk, row), with the row
              metrics.jsonl gets: {"chunk", "step", "seconds", "wall_s", each loss of the
              chunk's phase: [per seed]} and, when the chunk was evaluated (eval_every),
              "eval/<split>/<protocol>": [per seed] and "flops" (cumulative, per seed);
              "dropped": [seeds] once a seed was dropped (zsbfm.loggers builds on it).
    encoder_from: a finished run's directory whose config differs from cfg only in fields the
              encoder phase never reads (zsbfm.encoder_reuse.FB_PHASE_FIELDS, e.g. h_train_true,
              steps): a new run starts from the end of its encoder phase instead of redoing it,
              and equals the run trained from scratch (belief methods, encoder_mode="staged").

    The run holds its directory (zsbfm.lock: a second writer gets RunLocked); SIGINT and
    SIGTERM stop it at the next chunk boundary with `Interrupted` (zsbfm.interrupt); a
    seed that goes non-finite raises NonFiniteError or is dropped (Config.on_nonfinite).

    Multi-process (after jax.distributed.initialize; zsbfm.cli does it): every process
    calls this with the same cfg; runs_dir must be on a filesystem all processes share.
    Each process collects and trains its own devices' seeds; orbax writes the checkpoints
    together; process 0 alone holds the lock and writes config.json, metrics.jsonl,
    results.json and plots; the returned Run's params are replicated on every process.
    """
    primary = jax.process_index() == 0
    run_dir = os.path.abspath(os.path.join(cfg.runs_dir, cfg.run_name))
    encoder = encoder_checkpoint(cfg, encoder_from) if encoder_from else None  # before anything compiles
    with RunDirLock(run_dir) if primary else contextlib.nullcontext():
        run_dir = prepare_run_dir(cfg, resume)
        if encoder is not None:
            if primary:
                seed_from_encoder_run(run_dir, encoder_from, *encoder)
            _barrier("zsbfm: encoder phase copied")
        trainer = make_train(cfg, progress and primary)
        with StopSignals() as stop:  # from here to the saved run, a signal waits for a chunk boundary
            loop = run_loop(trainer, run_dir, seed_keys(cfg), {}, resume, progress, callback, stop=stop)
            old = _read_results(run_dir) if loop.start == cfg.num_chunks else None
            results = final_results(trainer, loop)
            results["wall_time_s"]["train"] = round(loop.train_seconds, 2)
            if old is not None:  # a finished run evaluated again: its training time is the original's
                results["wall_time_s"]["train"] = old.get("wall_time_s", {}).get("train", results["wall_time_s"]["train"])
            results["resumed_from_chunk"] = loop.start
            params = trainer.agent.eval_params(loop.carry.agent_state)
            if jax.process_count() > 1:  # each process holds only its seeds: gather them everywhere
                params = jax.jit(lambda p: p, out_shardings=replicated(loop.shard))(params)
            run = Run(cfg=cfg, params=params, results=results, metrics=loop.metrics)
            run.save(run_dir)
            if primary:
                try:
                    from zsbfm.plots import plot_run

                    plot_run(run, run_dir)
                except Exception as e:  # plots must never lose a finished run
                    print(f"warning: plotting failed: {e!r}")
    return run


def _read_results(run_dir: str) -> dict | None:
    path = os.path.join(run_dir, "results.json")
    if not os.path.exists(path):
        return None
    with open(path) as f:
        return json.load(f)


def final_results(trainer: Trainer, loop: LoopResult) -> dict:
    """results.json's content for the rows of `loop`: the official score per split and row
    ("train", "test"), its per-layout / per-goal detail, and every protocol's score
    ("protocols": {protocol: {split: [per row]}})."""
    t_eval = time.time()
    per_row = jax.vmap(trainer.evaluate)
    success = jax.jit(per_row, out_shardings=replicated(loop.shard))(loop.carry, loop.dataset, loop.keys, loop.hp)
    success = jax.device_get(success)
    results = {split: split_results(success[split])["success"] for split in ("train", "test")}
    results["detail"] = {split: split_results(success[split]) for split in ("train", "test")}
    last = loop.metrics[-1] if loop.metrics else {}
    if any(k.startswith("eval/") for k in last):  # the curve's last point is this very evaluation
        scores = {k[5:]: last[k] for k in last if k.startswith("eval/")}
    else:
        # the official protocol's score is the mean of `success` (same keys, same tasks): only
        # the other protocols need rollouts (none for eval_protocols="official" or antwind)
        official, *others = run_protocols(trainer.cfg, trainer.env)
        scores = {f"{split}/{official}": np.round(np.asarray(success[split], np.float32).mean((1, 2)), 4).tolist()
                  for split in ("train", "test")}
        if others:
            eval_others = jax.jit(jax.vmap(functools.partial(trainer.evaluate_protocols, skip_official=True)),
                                  out_shardings=replicated(loop.shard))
            more = jax.device_get(eval_others(loop.carry, loop.dataset, loop.keys, loop.hp))
            scores.update({k: np.round(np.asarray(v), 4).tolist() for k, v in more.items()})
    protocols: dict = {}
    for k, v in scores.items():
        split, protocol = k.split("/")
        protocols.setdefault(protocol, {})[split] = v
    results["protocols"] = protocols
    if loop.dropped:  # a dropped row's scores are those of its last finite state: not a result
        n, blank = len(results["train"]), loop.dropped
        results.update(_blank_rows({s: results[s] for s in ("train", "test")}, n, blank))
        results["detail"] = {s: _blank_rows(d, n, blank) for s, d in results["detail"].items()}
        results["protocols"] = {p: _blank_rows(d, n, blank) for p, d in protocols.items()}
        results["dropped"] = [{"seed": i, "chunk": c} for i, c in sorted(blank.items())]
    results["wall_time_s"] = {"train": round(loop.train_seconds, 2), "eval": round(time.time() - t_eval, 2)}
    results["metric"] = metric_of(trainer.env)
    return jsonable(results)


def _progress(cfg: Config, start: int, enabled: bool, label: str = ""):
    from tqdm.auto import tqdm

    return tqdm(total=cfg.num_chunks, initial=start, disable=not enabled, unit="chunk",
                desc=label or f"{cfg.run_name} ({cfg.num_seeds} seeds x {cfg.chunk_steps} steps/chunk)")
