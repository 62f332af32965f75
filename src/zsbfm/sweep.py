"""Hyperparameter sweeps through vmap: every grid point x seed of a sweep is one row of a
single compiled program.

    python -m zsbfm sweep --env fourrooms --algo oracle --grid lr=1e-4,3e-4 tau=0.01,0.05 --seeds 2

The grid's scalar settings (`config.SWEEPABLE`: learning rates, Polyak rates, gamma,
temperature, ...) enter the program as traced values (`Config.with_traced`), so a 2 x 3
grid of them with 2 seeds trains 12 rows with one compile. Fields that change shapes or
control flow (widths, batch, d, splus, ...) give one program per combination of their
values ("groups", trained one after another). Every point is validated as a concrete
Config before anything compiles, with the same one-line errors as `--set`.

A sweep writes runs/<name>/: sweep.json (the grid, and per point its official score and
every protocol's score per seed, and its learning curve if cfg.eval_every > 0), sweep.md
(the table), sweep.png (bars per point) and curves.png (learning curves, when logged);
each group trains in runs/<name>/g<i>/, checkpointed and resumable like a run, and each
point is saved as a plain run in runs/<name>/points/<j>/ (zsbfm.load, zsbfm.evaluate and
the diagnostics in experiments/fb_diagnostics work on it).

Like a run, a sweep holds its directory (zsbfm.lock), stops at a chunk boundary on SIGINT /
SIGTERM (zsbfm.interrupt), and stops or drops rows that go non-finite (Config.on_nonfinite):
a dropped row marks its point ("dropped" in sweep.json, the table and the plots).
"""

from __future__ import annotations

import contextlib
import dataclasses
import itertools
import json
import os
from typing import Any, Callable

import jax
import numpy as np

from zsbfm.config import SWEEPABLE, Config
from zsbfm.interrupt import StopSignals
from zsbfm.keys import seed_keys
from zsbfm.lock import RunDirLock
from zsbfm.run import Run
from zsbfm.train import final_results, make_train, prepare_run_dir, run_loop


def parse_grid(cfg: Config, items: list[str] | tuple[str, ...]) -> dict[str, list]:
    """["lr=1e-4,3e-4", "f_hidden=256/512,512"] -> {"lr": [1e-4, 3e-4], "f_hidden": [(256,), (512, 512)]}.

    Scalar values are comma-separated; a tuple field's alternatives are separated by "/"
    (each one comma-separated, as in --set). Each value is parsed and validated as
    `cfg.with_overrides` does, so a bad one fails with the same message."""
    grid: dict[str, list] = {}
    for item in items:
        if "=" not in item:
            raise ValueError(f"grid entry {item!r} must look like field=v1,v2,...")
        k, vals = item.split("=", 1)
        tuple_field = isinstance(getattr(cfg, k, None), tuple)
        alternatives = vals.split("/") if tuple_field else vals.split(",")
        if k in grid:
            raise ValueError(f"grid field {k!r} given twice")
        parsed = []
        for v in alternatives:
            if not v:
                raise ValueError(f"grid entry {item!r} has an empty value")
            parsed.append(getattr(cfg.with_overrides([f"{k}={v}"]), k))
        grid[k] = parsed
    if not grid:
        raise ValueError("an empty grid: give at least one field=v1,v2,...")
    return grid


def _label(point: dict) -> str:
    def fmt(v):
        return ",".join(map(str, v)) if isinstance(v, tuple) else f"{v:g}" if isinstance(v, float) else str(v)
    return " ".join(f"{k}={fmt(v)}" for k, v in point.items()) or "base"


@dataclasses.dataclass
class SweepResult:
    """One entry per grid point: its settings, its official and per-protocol scores per seed,
    and its learning curve (a list of {"step", "flops", "wall_s", "eval/...": [per seed]})."""

    cfg: Config
    grid: dict
    points: list[dict]
    path: str

    def table(self) -> str:
        """The Markdown table: one row per point, every protocol's mean +- std over seeds."""
        protos = sorted({p for pt in self.points for p in pt["protocols"]},
                        key=lambda p: (p != "paper", p))
        head = ["setting"] + [f"{split} {p}" for p in protos for split in ("train", "test")]
        lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        for pt in self.points:
            cells = [pt["label"] + (f" (seeds {pt['dropped']} dropped)" if pt.get("dropped") else "")]
            for p in protos:
                for split in ("train", "test"):
                    v = np.asarray(pt["protocols"].get(p, {}).get(split, [np.nan]), float)
                    v = v[np.isfinite(v)]  # a dropped seed's score is None
                    cells.append(f"{v.mean():.3f} +- {v.std():.3f}" if v.size else "dropped")
            lines.append("| " + " | ".join(cells) + " |")
        return "\n".join(lines)


def sweep(cfg: Config, grid: dict[str, list], resume: bool = True, progress: bool = True,
          callback: Callable[[int, dict], None] | None = None) -> SweepResult:
    """Train every point of `grid` ({field: [values]}) x cfg.num_seeds seeds; see the module
    docstring. Seed i of every point uses the key of seed i of a plain run of that point's
    Config, so a point's scores equal those of `zsbfm.train` on it (up to float summation
    order).

    callback: called on the host after each chunk of each point as callback(chunk, row), with
    the point's part of the chunk's metrics row (as `zsbfm.train` passes it: each loss
    [per seed], and when evaluated "eval/<split>/<protocol>" [per seed] and "flops") plus
    "point" (its index in SweepResult.points) and "label" (its settings)."""
    unknown = sorted(set(grid) - {f.name for f in dataclasses.fields(Config)})
    if unknown:
        raise ValueError(f"unknown Config fields {unknown} in the grid")
    scalar = {k: v for k, v in grid.items() if k in SWEEPABLE}
    shaped = {k: v for k, v in grid.items() if k not in SWEEPABLE}
    groups = [dict(zip(shaped, vals)) for vals in itertools.product(*shaped.values())]
    scalar_points = [dict(zip(scalar, vals)) for vals in itertools.product(*scalar.values())]
    # validate every point as a concrete Config before anything compiles
    plans = []
    for gi, group in enumerate(groups):
        cfg_g = dataclasses.replace(cfg, **group, name=f"{cfg.run_name}/g{gi}")
        for point in scalar_points:
            dataclasses.replace(cfg_g, **point)
        plans.append((group, cfg_g))
    root = os.path.abspath(os.path.join(cfg.runs_dir, cfg.run_name))
    with RunDirLock(root) if jax.process_index() == 0 else contextlib.nullcontext(), StopSignals() as stop:
        return _sweep(cfg, grid, plans, scalar, scalar_points, root, resume, progress, callback, stop)


def _point_row(row: dict, rows: slice, n_rows: int, point: int, label: str) -> dict:
    """The part of a sweep group's metrics row that belongs to one point (its seeds' rows)."""
    out = {k: (v[rows] if isinstance(v, list) and len(v) == n_rows else v) for k, v in row.items()
           if k != "dropped"}
    dropped = [i - rows.start for i in row.get("dropped", []) if rows.start <= i < rows.stop]
    return {**out, **({"dropped": dropped} if dropped else {}), "point": point, "label": label}


def _sweep(cfg, grid, plans, scalar, scalar_points, root, resume, progress, callback, stop) -> SweepResult:
    spec = {"grid": {k: [list(v) if isinstance(v, tuple) else v for v in vals] for k, vals in grid.items()}}
    points = []
    for gi, (group, cfg_g) in enumerate(plans):
        run_dir = prepare_run_dir(cfg_g, resume, extra=dict(spec, group=_jsonable(group)))
        trainer = make_train(cfg_g)
        n, S = len(scalar_points), cfg.num_seeds
        keys = np.tile(np.asarray(seed_keys(cfg_g)), (n, 1))                # row = point * S + seed
        hp = {k: np.repeat(np.asarray([p[k] for p in scalar_points], np.float32), S) for k in scalar}
        label = f"sweep {cfg.run_name} group {gi + 1}/{len(plans)} ({n} points x {S} seeds)"
        labels = [_label({**group, **point}) for point in scalar_points]
        first = len(points)  # the index of this group's first point

        def point_rows(chunk, row):
            for pi in range(n):
                callback(chunk, _point_row(row, slice(pi * S, (pi + 1) * S), n * S, first + pi, labels[pi]))

        loop = run_loop(trainer, run_dir, keys, hp, resume, progress, callback=point_rows if callback else None,
                        label=label, stop=stop, row_name=lambda i: f"point {first + i // S} ({labels[i // S]}) seed {i % S}")
        res = final_results(trainer, loop)
        params = jax.device_get(trainer.agent.eval_params(loop.carry.agent_state))
        for pi, point in enumerate(scalar_points):
            rows = slice(pi * S, (pi + 1) * S)
            settings = {**group, **point}
            # each point is also saved as a plain run: zsbfm.load / zsbfm.evaluate work on it
            point_cfg = dataclasses.replace(cfg_g, **point, name=f"{cfg.run_name}/points/{len(points)}")
            point_results = {k: (v[rows] if k in ("train", "test") else v) for k, v in res.items()}
            point_results["detail"] = {sp: {k: v[rows] for k, v in d.items()} for sp, d in res["detail"].items()}
            point_results["protocols"] = {p: {sp: v[rows] for sp, v in d.items()} for p, d in res["protocols"].items()}
            dropped = [i - rows.start for i in sorted(loop.dropped) if rows.start <= i < rows.stop]
            point_results.pop("dropped", None)
            if dropped:
                point_results["dropped"] = [{"seed": i, "chunk": loop.dropped[rows.start + i]} for i in dropped]
            point_metrics = [{k: v for k, v in _point_row(m, rows, n * S, len(points), "").items()
                              if k not in ("point", "label")} for m in loop.metrics]
            Run(cfg=point_cfg, params=jax.tree_util.tree_map(lambda x: x[rows], params),
                results=point_results, metrics=point_metrics).save(os.path.join(root, "points", str(len(points))))
            curve = [{k: (v[rows] if isinstance(v, list) and k.startswith("eval/") else v)
                      for k, v in m.items() if k in ("step", "flops", "wall_s") or k.startswith("eval/")}
                     for m in loop.metrics if any(k.startswith("eval/") for k in m)]
            points.append({"label": _label(settings), "settings": _jsonable(settings), "group": gi,
                           "train": res["train"][rows], "test": res["test"][rows],
                           "protocols": {p: {s: v[rows] for s, v in d.items()} for p, d in res["protocols"].items()},
                           "curve": curve, "train_seconds_group": round(loop.train_seconds, 1),
                           **({"dropped": dropped} if dropped else {})})
    result = SweepResult(cfg=cfg, grid=grid, points=points, path=root)
    with open(os.path.join(root, "sweep.json"), "w") as f:
        json.dump({**spec, "config": cfg.to_dict(), "points": points}, f, indent=1)
    with open(os.path.join(root, "sweep.md"), "w") as f:
        f.write(f"# sweep {cfg.run_name}: {cfg.env} {cfg.algo}, {cfg.num_seeds} seeds, {cfg.steps} steps\n\n")
        f.write(result.table() + "\n")
    try:
        from zsbfm.plots import plot_sweep

        plot_sweep(result, root)
    except Exception as e:  # plots must never lose a finished sweep
        print(f"warning: plotting failed: {e!r}")
    return result


def _jsonable(d: dict) -> dict:
    return {k: list(v) if isinstance(v, tuple) else v for k, v in d.items()}


def load_sweep(path: str) -> dict[str, Any]:
    """sweep.json of a finished sweep."""
    with open(os.path.join(path, "sweep.json")) as f:
        return json.load(f)
