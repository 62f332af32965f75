"""Start a belief run's FB phase from another run's encoder phase (`train(..., encoder_from=)`).

With encoder_mode="staged", a Belief-FB / Rotation-FB run spends its first enc_steps updates
on the encoder alone: F and B stay at their initial values and the fields only the FB phase
reads (FB_PHASE_FIELDS) are never used. Two runs whose configs differ only in those fields
therefore hold the same state at the end of the encoder phase, chunk enc_steps / chunk_steps.
`seed_from_encoder_run` copies that chunk's checkpoint and metrics rows from the finished
encoder run into the new run's directory, which then resumes there as after an
interruption: the result is the run trained from scratch, bit for bit, without redoing the
encoder phase (tests/test_train.py checks it). Anything else that differs (F's widths,
the learning rate, the seed) changes the state at that chunk, and is an error.
"""
from __future__ import annotations

import dataclasses
import json
import os
import shutil

from zsbfm.config import BELIEF_ALGOS, Config
from zsbfm.run import read_metrics

# Fields the encoder phase never reads: where they differ the state at its end is the same.
FB_PHASE_FIELDS = ("name", "runs_dir", "steps", "eval_every", "h_train_true", "h_train_mask",
                   "data_parallel", "on_nonfinite")


def encoder_checkpoint(cfg: Config, encoder_run: str) -> tuple[str, int]:
    """(the encoder run's checkpoint folder at the end of its encoder phase, that chunk), after
    checking that `cfg` may start from it; a ValueError naming what is wrong otherwise. Reads
    files only: call it before anything compiles."""
    if cfg.algo not in BELIEF_ALGOS or cfg.encoder_mode != "staged":
        raise ValueError(f"encoder_from={encoder_run!r} needs a staged belief run (algo one of {BELIEF_ALGOS}, "
                         f"encoder_mode='staged'), got algo={cfg.algo!r}, encoder_mode={cfg.encoder_mode!r}")
    if not cfg.checkpoint:
        raise ValueError(f"encoder_from={encoder_run!r} needs checkpoint=True (the run starts from a checkpoint)")
    cfg_path = os.path.join(encoder_run, "config.json")
    if not os.path.exists(cfg_path):
        raise ValueError(f"encoder_from={encoder_run!r}: no run there (no config.json)")
    with open(cfg_path) as f:
        other = Config.from_dict(json.load(f))
    diff = {f.name: (getattr(other, f.name), getattr(cfg, f.name)) for f in dataclasses.fields(Config)
            if f.name not in FB_PHASE_FIELDS and getattr(other, f.name) != getattr(cfg, f.name)}
    if diff:
        raise ValueError(f"encoder_from={encoder_run!r} ran another encoder phase: {diff} differ "
                         f"(encoder run, this run); only {FB_PHASE_FIELDS} may")
    chunk = cfg.enc_steps // cfg.chunk_steps
    folder = os.path.join(encoder_run, "checkpoints", str(chunk))
    if not os.path.isdir(folder):
        kept = sorted(int(c) for c in os.listdir(os.path.dirname(folder)) if c.isdigit()) \
            if os.path.isdir(os.path.dirname(folder)) else []
        raise ValueError(f"encoder_from={encoder_run!r} has no checkpoint at chunk {chunk}, the end of its "
                         f"encoder phase (it keeps {kept}: a run keeps its last two chunks, so train the "
                         f"encoder run with steps = enc_steps + chunk_steps)")
    return folder, chunk


def seed_from_encoder_run(run_dir: str, encoder_run: str, folder: str, chunk: int) -> bool:
    """Copy the encoder phase (checkpoint `folder` of chunk `chunk`, and the metrics rows up to
    it) into run_dir, unless run_dir already has a checkpoint (then it resumes its own).
    Returns whether it copied."""
    ckpts = os.path.join(run_dir, "checkpoints")
    if os.path.isdir(ckpts) and any(c.isdigit() for c in os.listdir(ckpts)):
        return False
    shutil.copytree(folder, os.path.join(ckpts, str(chunk)))
    with open(os.path.join(run_dir, "metrics.jsonl"), "w") as f:
        f.writelines(json.dumps(row, allow_nan=False) + "\n" for row in read_metrics(encoder_run, chunk))
    return True
