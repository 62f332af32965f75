"""Command line: `python -m zsbfm {train,sweep,evaluate,collect} ...` (see --help).

Exit codes: 0 done; 2 bad input (one line naming the value, before anything compiles);
3 a seed went non-finite (Config.on_nonfinite="stop"); 4 the run directory is in use by
another process (zsbfm.lock); 130 / 143 stopped by SIGINT / SIGTERM at a chunk boundary
(zsbfm.interrupt: run the same command again to resume).

The help texts name what the code accepts, read from where the code keeps it: environments
from their registry, algorithms and preset sizes from zsbfm.names.
"""

from __future__ import annotations

import json
import os
import sys

import tyro

from zsbfm.envs.registry import env_names, env_spec
from zsbfm.names import ALGOS, SIZES

ALGO_NOTES = {"fb": "Forward-Backward", "bfb": "Belief-FB", "rfb": "Rotation-FB",
              "oracle": "FB told the true context, a diagnostic", "hilp": "HILP", "lap": "Laplacian",
              "random": "uniform actions"}
SIZE_NOTES = {"cpu": "the default, minutes per seed on a 2-core CPU", "long": "cpu with more updates",
              "paper": "the paper's Table 4 sizes, for a GPU", "authors": "the authors' public code's settings"}


def _choices(names, notes: dict) -> str:
    return " | ".join(f"{n} ({notes[n]})" if notes.get(n) else n for n in names)


def _sizes_help() -> str:
    """Every preset size, and the environments that have it when not all do."""
    parts = []
    for size in SIZES:
        envs = [e for e in env_names() if size in env_spec(e).presets]
        notes = [SIZE_NOTES.get(size, ""), "" if len(envs) == len(env_names()) else f"{', '.join(envs)} only"]
        notes = "; ".join(n for n in notes if n)
        parts.append(f"{size} ({notes})" if notes else size)
    return " | ".join(parts)


def _shared_data_envs() -> str:
    return ", ".join(e for e in env_names() if env_spec(e).shares_data) or "none"


def _with_names(fn):
    """fn's docstring with {envs}, {algos}, {sizes} and {shared_data_envs} filled in from
    the code (what tyro shows as --help)."""
    names = {"{envs}": " | ".join(env_names()), "{algos}": _choices(ALGOS, ALGO_NOTES),
             "{sizes}": _sizes_help(), "{shared_data_envs}": _shared_data_envs()}
    for placeholder, text in names.items():
        fn.__doc__ = fn.__doc__.replace(placeholder, text)
    return fn


@_with_names
def train(env: str = "fourrooms", algo: str = "fb", seeds: int = 3, size: str = "cpu",
          name: str = "", runs_dir: str = "runs", resume: bool = True, dataset: str = "",
          set: tuple[str, ...] = (), log: tuple[str, ...] = (), coordinator: str = "",
          num_processes: int = 0, process_id: int = -1, encoder_from: str = "") -> None:
    """Train all seeds of a preset together (vmapped), evaluate on train and test layouts.

    Args:
        env: environment: {envs}.
        algo: algorithm: {algos}.
        seeds: number of seeds, trained together with jax.vmap.
        size: preset sizes: {sizes}.
        name: run name (default <env>-<algo>-<size>); output goes to <runs_dir>/<name>/.
        runs_dir: where runs are written.
        resume: continue from this run's newest checkpoint (--no-resume: start afresh).
        dataset: train on a saved dataset (.npz from `python -m zsbfm collect`, or your own
            with the arrays obs, action, context_id) instead of collecting one per seed.
        set: Config overrides as field=value, e.g. --set steps=2000 lr=1e-3 f_hidden=512,512.
        log: also log every chunk's losses (and learning curve) to: tensorboard (event files in
            <run>/tensorboard/) | wandb (needs `pip install 'zsbfm[wandb]'`).
        coordinator: multi-process run: HOST:PORT of process 0 (default $JAX_COORDINATOR_ADDRESS);
            run the same command on every host with its own --process-id.
        num_processes: multi-process run: number of processes (default $JAX_NUM_PROCESSES).
        process_id: multi-process run: this process's index, 0..num_processes-1 (default $JAX_PROCESS_ID).
        encoder_from: a finished belief run (runs/<name>) whose config differs only in fields the
            encoder phase never reads (h_train_true, steps, ...): start from the end of its
            encoder phase instead of redoing it (the same run, bit for bit).
    """
    init_distributed(coordinator, num_processes, process_id)  # before anything touches a device
    from zsbfm.config import Config
    from zsbfm.loggers import as_callback
    from zsbfm.train import train as run_train

    cfg = Config.preset(env, algo, size, num_seeds=seeds, name=name, runs_dir=runs_dir).with_overrides(set)
    if dataset:
        cfg = cfg.replace(dataset=dataset)
    import jax

    with _loggers(log, cfg) as loggers:
        run = run_train(cfg, resume=resume, callback=as_callback(loggers), encoder_from=encoder_from)
    if jax.process_index() == 0:
        _print_results(run)


def _loggers(kinds, cfg):
    """The --log loggers of cfg's run directory (process 0 alone logs a multi-process run)."""
    import jax

    from zsbfm.loggers import make_loggers

    kinds = kinds if jax.process_index() == 0 else ()
    return make_loggers(kinds, os.path.join(cfg.runs_dir, cfg.run_name), cfg.run_name, cfg.to_dict())


def init_distributed(coordinator: str = "", num_processes: int = 0, process_id: int = -1) -> bool:
    """jax.distributed.initialize for a multi-process run, if one is asked for (a coordinator
    or more than one process, from the arguments or $JAX_COORDINATOR_ADDRESS,
    $JAX_NUM_PROCESSES, $JAX_PROCESS_ID); returns whether it did. Must run before any JAX
    computation or device query. CPU cross-process collectives use gloo over TCP."""
    coordinator = coordinator or os.environ.get("JAX_COORDINATOR_ADDRESS", "")
    num_processes = num_processes or int(os.environ.get("JAX_NUM_PROCESSES", "0"))
    process_id = process_id if process_id >= 0 else int(os.environ.get("JAX_PROCESS_ID", "-1"))
    if not coordinator and num_processes <= 1:
        return False
    if not coordinator or num_processes < 1 or not 0 <= process_id < num_processes:
        raise ValueError(f"multi-process run needs --coordinator HOST:PORT, --num-processes N and "
                         f"--process-id 0..N-1; got coordinator={coordinator!r}, "
                         f"num_processes={num_processes}, process_id={process_id}")
    import jax

    jax.config.update("jax_cpu_collectives_implementation", "gloo")
    jax.distributed.initialize(coordinator_address=coordinator, num_processes=num_processes,
                               process_id=process_id)
    return True


def evaluate(path: tyro.conf.Positional[str], split: str = "test", protocol: str = "", draws: int = 1) -> None:
    """Evaluate a saved run on a split and print its score per seed (success rate, or episode
    return for antwind): with the run's own evaluation keys, the numbers it reported.

    Args:
        path: the run directory, e.g. runs/fourrooms-fb-cpu.
        split: train | test.
        protocol: "" for the official score; or one of the env's protocols (gridworlds:
            paper, dense, random_start; pointmass: paper, dense).
        draws: 1 for the run's own draw of context episodes and rollouts; N > 1 also scores
            N - 1 fresh draws (zsbfm.evaluate.score_draws) and adds each seed's mean over the
            N and its standard error (sample std / sqrt N).
    """
    import numpy as np

    from zsbfm.evaluate import score_draws, standard_error
    from zsbfm.run import load

    run = load(path)
    scores = np.asarray(score_draws(run, draws, split, protocol or None))  # [draws, seeds]
    metric = run.results.get("metric", "success")
    out = {"split": split, "protocol": protocol or "official",
           f"{metric}_per_seed": scores[0].round(4).tolist(), "mean": round(float(scores[0].mean()), 4)}
    if draws > 1:
        out.update(draws=draws, mean_over_draws_per_seed=scores.mean(0).round(4).tolist(),
                   se_per_seed=standard_error(scores).round(4).tolist(),
                   mean_over_draws=round(float(scores.mean()), 4))
    print(json.dumps(out))


@_with_names
def collect(env: str = "fourrooms", n_train: int = 0, episodes_per_layout: int = 0,
            seed: int = 0, out: str = "") -> None:
    """Collect the behaviour policy's episodes in the train contexts and save them as a dataset.

    Most environments' data is collected afresh for every seed during training; this saves
    one such dataset as an .npz file, for `train --dataset`. Where the data is one dataset
    shared by every seed ({shared_data_envs}: recorded from a trained behaviour expert), this
    trains or loads the expert, records the dataset and caches it under the preset's data_dir,
    where `train --env <env>` reads it; --out is then ignored.

    Args:
        env: environment: {envs}.
        n_train: train contexts (layouts, mazes); 0: the environment's CPU preset.
        episodes_per_layout: episodes in each train context; 0: the environment's CPU preset.
        seed: the key of the collection.
        out: the .npz file (default datasets/<env>-<n_train>x<episodes>-seed<seed>.npz).
    """
    import time

    import jax

    from zsbfm.config import Config
    from zsbfm.data import collect as collect_data
    from zsbfm.data import save_dataset
    from zsbfm.data.sources import make_env_for, shared_dataset

    cfg = Config.preset(env, seed=seed, **({"n_train_layouts": n_train} if n_train else {}),
                        **({"episodes_per_layout": episodes_per_layout} if episodes_per_layout else {}))
    t = time.time()
    e = make_env_for(cfg)  # with its behaviour expert when the env's data comes from one
    ds = shared_dataset(cfg, e)  # None unless the env's data is one dataset for every seed
    if ds is not None:
        print(f"{env} dataset: {ds.num_transitions} transitions ready in {time.time() - t:.0f}s "
              f"(cached under {cfg.data_dir}/, where `train --env {env}` reads it)")
        return
    ds = jax.jit(lambda k: collect_data(e, k, e.contexts("train"), cfg.episodes_per_layout))(jax.random.PRNGKey(seed))
    ds.obs.block_until_ready()
    out = out or os.path.join("datasets", f"{env}-{cfg.n_train_layouts}x{cfg.episodes_per_layout}-seed{seed}.npz")
    save_dataset(out, ds)
    print(f"{ds.num_transitions} transitions in {time.time() - t:.2f}s -> {out}")


@_with_names
def sweep(env: str = "fourrooms", algo: str = "fb", seeds: int = 2, size: str = "cpu",
          name: str = "", runs_dir: str = "runs", resume: bool = True,
          grid: tuple[str, ...] = (), set: tuple[str, ...] = (), log: tuple[str, ...] = ()) -> None:
    """Train every combination of a grid of settings x seeds, vmapped in one compiled program
    per group of shape-changing values; writes runs/<name>/sweep.{json,md,png}.

    Args:
        env: environment: {envs}.
        algo: algorithm: {algos}.
        seeds: seeds per grid point.
        size: preset sizes: {sizes}.
        name: sweep name (default sweep-<env>-<algo>); output in <runs_dir>/<name>/.
        runs_dir: where runs are written.
        resume: continue from this sweep's checkpoints (--no-resume: start afresh).
        grid: field=v1,v2,... per swept field, e.g. --grid lr=1e-4,3e-4 tau=0.01,0.05;
            a tuple field's alternatives are separated by '/', e.g. f_hidden=256/512,512.
        set: Config overrides applied to every point, as in train.
        log: also log every point's chunks to: tensorboard (<sweep>/tensorboard/point<j>/) | wandb.
    """
    from zsbfm.config import Config
    from zsbfm.loggers import as_callback
    from zsbfm.sweep import parse_grid
    from zsbfm.sweep import sweep as run_sweep

    cfg = Config.preset(env, algo, size, num_seeds=seeds, name=name or f"sweep-{env}-{algo}",
                        runs_dir=runs_dir).with_overrides(set)
    parsed = parse_grid(cfg, grid)
    with _loggers(log, cfg) as loggers:
        result = run_sweep(cfg, parsed, resume=resume, callback=as_callback(loggers))
    print(result.table())
    print(f"->  {result.path}")


def _print_results(run) -> None:
    import numpy as np

    r = run.results
    kept = lambda values: np.asarray([x for x in values if x is not None], float)  # noqa: E731  (dropped seeds: None)
    for split in ("train", "test"):
        v = kept(r[split])
        per_seed = [None if x is None else round(x, 3) for x in r[split]]
        print(f"{split:5s} {r.get('metric', 'success')}: {v.mean():.3f} +- {v.std():.3f}  per seed {per_seed}")
    for protocol, scores in r.get("protocols", {}).items():
        print(f"  protocol {protocol:12s} " + "  ".join(
            f"{split} {kept(v).mean():.3f}" for split, v in scores.items()))
    for d in r.get("dropped", []):
        print(f"seed {d['seed']} dropped: non-finite in chunk {d['chunk']}")
    print(f"wall time: {r['wall_time_s']}  ->  {os.path.join(run.cfg.runs_dir, run.cfg.run_name)}")


def main(argv=None) -> None:
    from zsbfm.interrupt import Interrupted
    from zsbfm.lock import RunLocked
    from zsbfm.nonfinite import NonFiniteError

    try:
        tyro.extras.subcommand_cli_from_dict(
            {"train": train, "sweep": sweep, "evaluate": evaluate, "collect": collect}, args=argv,
            prog="python -m zsbfm")
    except (ValueError, FileNotFoundError) as e:  # bad input: one clear line, no traceback
        print(f"error: {e}", file=sys.stderr)
        sys.exit(2)
    except NonFiniteError as e:
        print(f"error: {e}", file=sys.stderr)
        sys.exit(3)
    except RunLocked as e:
        print(f"error: {e}", file=sys.stderr)
        sys.exit(4)
    except Interrupted as e:  # everything up to the last chunk is written
        print(f"interrupted: {e}", file=sys.stderr)
        sys.exit(e.exit_code)
