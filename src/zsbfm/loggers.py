"""Loggers built on the training callback: `callback(chunk, row)` of zsbfm.train and
zsbfm.sweep.sweep, called on the host after every chunk with the chunk's metrics row (each
loss [per seed]; when evaluated, "eval/<split>/<protocol>" [per seed] and cumulative
"flops"; a sweep's rows also carry "point" and "label").

    with TensorBoardLogger("runs/x/tensorboard") as tb:   # python -m zsbfm train --log tensorboard
        zsbfm.train(cfg, callback=tb)

Each per-seed value is a scalar "<name>/seed<i>" at the row's update count; a sweep's
points are written as runs of their own (point<j>/), which TensorBoard draws side by side.
`--log wandb` sends the same scalars to Weights & Biases (the optional extra `zsbfm[wandb]`;
WANDB_MODE=offline works without a network).
"""

from __future__ import annotations

import importlib.util
import os
from typing import Callable

LOGGERS = ("tensorboard", "wandb")
NOT_LOGGED = ("chunk", "step", "point", "label", "dropped")


def scalars(row: dict) -> dict[str, float]:
    """The numbers of a metrics row as flat scalar names: {"fb_loss/seed0": ..., "flops": ...}
    (a dropped seed's None is left out)."""
    out = {}
    for k, v in row.items():
        if k in NOT_LOGGED:
            continue
        if isinstance(v, list):
            out.update({f"{k}/seed{i}": float(x) for i, x in enumerate(v) if x is not None})
        elif isinstance(v, (int, float)) and not isinstance(v, bool):
            out[k] = float(v)
    return out


class TensorBoardLogger:
    """Writes every row as TensorBoard scalars under `logdir` (a sweep's points under
    logdir/point<j>/), with tensorboardX; the event files are created on the first row."""

    def __init__(self, logdir: str):
        self.logdir = logdir
        self.writers: dict = {}

    def __call__(self, chunk: int, row: dict) -> None:
        from tensorboardX import SummaryWriter

        point = row.get("point")
        if point not in self.writers:
            path = self.logdir if point is None else os.path.join(self.logdir, f"point{point}")
            self.writers[point] = SummaryWriter(path)
        writer = self.writers[point]
        for name, value in scalars(row).items():
            writer.add_scalar(name, value, row["step"])
        writer.flush()

    def close(self) -> None:
        for writer in self.writers.values():
            writer.close()
        self.writers = {}

    def __enter__(self) -> "TensorBoardLogger":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class WandbLogger:
    """Sends every row to Weights & Biases: one wandb run named after the zsbfm run, its
    files under the run directory, its config the zsbfm Config (a sweep's points prefixed
    "point<j>/")."""

    def __init__(self, run_dir: str, name: str, config: dict):
        if importlib.util.find_spec("wandb") is None:
            raise ValueError("--log wandb needs the wandb package, which is not installed: "
                             "pip install 'zsbfm[wandb]' (WANDB_MODE=offline logs without a network)")
        self.run_dir, self.name, self.config = run_dir, name, config
        self.run = None

    def __call__(self, chunk: int, row: dict) -> None:
        import wandb

        if self.run is None:
            os.makedirs(self.run_dir, exist_ok=True)
            self.run = wandb.init(project=os.environ.get("WANDB_PROJECT", "zsbfm"), name=self.name,
                                  dir=self.run_dir, config=self.config)
        prefix = "" if row.get("point") is None else f"point{row['point']}/"
        self.run.log({prefix + k: v for k, v in scalars(row).items()}, step=row["step"])

    def close(self) -> None:
        if self.run is not None:
            self.run.finish()
            self.run = None

    def __enter__(self) -> "WandbLogger":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class Loggers:
    """Several loggers behind one callback (what --log builds)."""

    def __init__(self, loggers: list):
        self.loggers = loggers

    def __call__(self, chunk: int, row: dict) -> None:
        for logger in self.loggers:
            logger(chunk, row)

    def close(self) -> None:
        for logger in self.loggers:
            logger.close()

    def __enter__(self) -> "Loggers":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def make_loggers(kinds, run_dir: str, name: str, config: dict) -> Loggers:
    """The loggers of `--log` for the run in `run_dir`, checked before anything compiles: an
    unknown kind, or wandb without its package, is a one-line ValueError."""
    made = []
    for kind in kinds:
        if kind == "tensorboard":
            made.append(TensorBoardLogger(os.path.join(run_dir, "tensorboard")))
        elif kind == "wandb":
            made.append(WandbLogger(run_dir, name, config))
        else:
            raise ValueError(f"--log {kind!r} is invalid: expected one of {LOGGERS}")
    return Loggers(made)


def as_callback(loggers: Loggers) -> Callable | None:
    """The callback to hand zsbfm.train / sweep: None when nothing logs."""
    return loggers if loggers.loggers else None
