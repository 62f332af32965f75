"""A finished training run: config, per-seed parameters, results and metrics, on disk.

Layout of a run directory (`runs/<name>/` by default):

    config.json     the Config
    results.json    success per split and seed, per layout, per goal, wall times
    metrics.jsonl   one line per compiled chunk: step and each metric per seed
    .lock           while a process trains it (zsbfm.lock)
    params/         orbax checkpoint of the agent's evaluation parameters (leading axis = seeds)
    checkpoints/    orbax checkpoints of the full training state, for resuming
    *.png           plots
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from typing import Any

import jax
import orbax.checkpoint as ocp

from zsbfm.config import Config


def jsonable(obj):
    """obj with every non-finite float replaced by None, so it writes as strict JSON (a NaN
    written as the bare token `NaN` is not JSON; readers that follow the standard reject it)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    return obj


def write_text(path: str, text: str) -> None:
    """Write a whole file atomically: a reader, or a run killed meanwhile, sees the old
    content or the new one, never half of it."""
    tmp = f"{path}.tmp-{os.getpid()}"
    with open(tmp, "w") as f:
        f.write(text)
    os.replace(tmp, path)


@dataclasses.dataclass
class Run:
    cfg: Config
    params: Any                 # evaluation params, every leaf with a leading seed axis
    results: dict               # {"train": [success per seed], "test": [...], ...}
    metrics: list = dataclasses.field(default_factory=list)

    def seed_params(self, seed: int) -> Any:
        """The evaluation params of one seed (the seed axis indexed away)."""
        return jax.tree_util.tree_map(lambda x: x[seed], self.params)

    def save(self, path: str | None = None) -> str:
        """Write config, results, metrics and an orbax checkpoint of params to `path`.

        Multi-process: every process calls it; process 0 writes the JSON files, orbax
        writes params once (force=True: the primary process replaces an old one)."""
        path = os.path.abspath(path or os.path.join(self.cfg.runs_dir, self.cfg.run_name))
        os.makedirs(path, exist_ok=True)
        if jax.process_index() == 0:
            write_text(os.path.join(path, "config.json"), self.cfg.to_json())
            write_text(os.path.join(path, "results.json"), json.dumps(jsonable(self.results), indent=2, allow_nan=False))
            write_text(os.path.join(path, "metrics.jsonl"),
                       "".join(json.dumps(jsonable(row), allow_nan=False) + "\n" for row in self.metrics))
        params_dir = os.path.join(path, "params")
        ckptr = ocp.StandardCheckpointer()
        ckptr.save(params_dir, self.params, force=True)
        ckptr.wait_until_finished()
        return path


def abstract_params(cfg: Config):
    """Shapes/dtypes of the stacked evaluation params of `cfg` (no computation)."""
    from zsbfm.agents import make_agent
    from zsbfm.envs import make_env

    env = make_env(cfg.env, n_train=cfg.n_train_layouts, episode_len=cfg.episode_len)
    agent = make_agent(cfg, env)
    keys = jax.random.split(jax.random.PRNGKey(0), cfg.num_seeds)
    return jax.eval_shape(lambda k: jax.vmap(lambda kk: agent.eval_params(agent.init(kk)))(k), keys)


def read_metrics(run_dir: str, upto_chunk: int) -> list[dict]:
    """The metrics.jsonl rows of run_dir's chunks up to `upto_chunk` ([] without the file);
    a last line cut short by a hard kill ends the read (its chunk is redone on resume)."""
    path = os.path.join(run_dir, "metrics.jsonl")
    if not os.path.exists(path):
        return []
    rows = []
    with open(path) as f:
        for line in f:
            try:
                rows.append(json.loads(line))
            except json.JSONDecodeError:
                break
    return [r for r in rows if r["chunk"] <= upto_chunk]


def load(path: str) -> Run:
    """Load a run saved by `Run.save` (or written by `zsbfm.train`)."""
    path = os.path.abspath(path)
    if not os.path.exists(os.path.join(path, "config.json")):
        raise FileNotFoundError(f"{path} is not a zsbfm run directory (no config.json)")
    with open(os.path.join(path, "config.json")) as f:
        cfg = Config.from_dict(json.load(f))
    with open(os.path.join(path, "results.json")) as f:
        results = json.load(f)
    metrics = []
    if os.path.exists(os.path.join(path, "metrics.jsonl")):
        with open(os.path.join(path, "metrics.jsonl")) as f:
            metrics = [json.loads(line) for line in f if line.strip()]
    # onto this process's first device, whatever devices wrote it (a sharded run's params too)
    on_device = jax.sharding.SingleDeviceSharding(jax.local_devices()[0])
    target = jax.tree_util.tree_map(lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=on_device),
                                    abstract_params(cfg))
    params = ocp.StandardCheckpointer().restore(os.path.join(path, "params"), target)
    return Run(cfg=cfg, params=params, results=results, metrics=metrics)
