"""A run that guards itself: non-finite seeds, SIGINT / SIGTERM, one writer per directory."""

import json
import math
import os
import random
import re
import signal
import socket
import subprocess
import sys
import time

import jax
import numpy as np
import orbax.checkpoint as ocp
import pytest

import zsbfm
from conftest import strict_lines, written_chunks
from zsbfm.cli import main
from zsbfm.lock import LOCK_NAME, RunDirLock, RunLocked
from zsbfm.sweep import parse_grid, sweep

ROOT = os.path.join(os.path.dirname(__file__), "..")
# the tiny Four-Rooms FB of conftest.tiny_config, as --set arguments
TINY = ["n_train_layouts=4", "episodes_per_layout=20", "d=8", "f_pre_hidden=16", "f_pre_out=16", "f_hidden=32",
        "b_hidden=16", "batch_size=32", "eval_episode_len=20", "context_len=20", "eval_protocols=official"]
# lr 450 makes one seed of the two diverge after tens of updates (with the gridworld preset of
# 727d249: seed 1, in chunk 4, updates 61-80) while the other stays finite; a preset change
# may move which seed and chunk, the test reads them from the error line
DIVERGING = TINY + ["lr=450", "steps=120", "chunk_steps=20"]


def finite_tree(tree) -> bool:
    return all(np.isfinite(np.asarray(x)).all() for x in jax.tree_util.tree_leaves(tree)
               if np.issubdtype(np.asarray(x).dtype, np.floating))


def test_a_diverging_seed_stops_the_run_in_one_line_and_drop_finishes_the_other(tmp_path, capsys):
    argv = ["train", "--seeds", "2", "--runs-dir", str(tmp_path), "--name", "div", "--set", *DIVERGING]
    with pytest.raises(SystemExit) as e:
        main(argv)
    assert e.value.code == 3
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip() and not line.startswith("div (")]
    assert len(err) == 1 and err[0].startswith("error: non-finite training"), err
    m = re.search(r"in chunk (\d)/6 .*: seed (\d): fb_loss = nan \(last finite \S+ in chunk \d\); "
                  r"the checkpoint of chunk (\d) is kept; to finish the other seeds, run again with "
                  r"--set on_nonfinite=drop$", err[0])
    assert m, f"expected one seed to diverge after chunk 1 and the other to stay finite: {err[0]}"
    chunk, seed, kept = int(m[1]), int(m[2]), int(m[3])
    assert kept == chunk - 1 >= 1 and err[0].count("seed ") == 1
    run_dir = tmp_path / "div"
    # the last finite checkpoint is kept, and holds finite parameters; nothing of the chunk was written
    assert ocp.CheckpointManager(str(run_dir / "checkpoints")).latest_step() == kept
    assert finite_tree(ocp.StandardCheckpointer().restore(str(run_dir / "checkpoints" / str(kept) / "default")))
    assert [r["chunk"] for r in strict_lines(run_dir / "metrics.jsonl")] == list(range(1, chunk))
    assert not (run_dir / "results.json").exists() and not (run_dir / LOCK_NAME).exists()

    # the same run with on_nonfinite=drop resumes there, drops that seed and finishes the other
    main([*argv, "on_nonfinite=drop"])
    assert f"seed {seed} dropped: non-finite in chunk {chunk}" in capsys.readouterr().out
    results = json.loads((run_dir / "results.json").read_text(), parse_constant=lambda c: pytest.fail(c))
    assert results["resumed_from_chunk"] == kept and results["dropped"] == [{"seed": seed, "chunk": chunk}]
    assert results["train"][seed] is None and results["train"][1 - seed] is not None
    rows = strict_lines(run_dir / "metrics.jsonl")
    assert [r.get("dropped") for r in rows] == [None] * kept + [[seed]] * (6 - kept)
    assert rows[-1]["fb_loss"][seed] is None and math.isfinite(rows[-1]["fb_loss"][1 - seed])
    run = zsbfm.load(str(run_dir))
    assert finite_tree(run.params)  # the dropped seed keeps its last finite parameters


def test_drop_in_a_sweep_marks_the_point_and_leaves_the_other_points_unchanged(tmp_path):
    """Point lr=1e4 (non-finite in its first chunk) is marked dropped; point lr=1e-3 ends
    bit-identical to the same point of a sweep where nothing diverged (the same compiled
    program: lr is a traced setting)."""
    cfg = zsbfm.Config.preset("fourrooms", "fb", num_seeds=1, runs_dir=str(tmp_path)).with_overrides(
        [*TINY, "steps=40", "chunk_steps=20", "on_nonfinite=drop"])
    diverged = sweep(cfg.replace(name="a"), parse_grid(cfg, ["lr=1e-3,1e4"]), progress=False)
    calm = sweep(cfg.replace(name="b"), parse_grid(cfg, ["lr=1e-3,2e-3"]), progress=False)
    assert diverged.points[1]["dropped"] == [0] and "dropped" not in diverged.points[0]
    assert diverged.points[1]["train"] == [None]
    assert "| lr=10000 (seeds [0] dropped) | dropped | dropped |" in diverged.table()
    assert diverged.points[0]["protocols"] == calm.points[0]["protocols"]
    a, b = zsbfm.load(str(tmp_path / "a" / "points" / "0")), zsbfm.load(str(tmp_path / "b" / "points" / "0"))
    for x, y in zip(jax.tree_util.tree_leaves(a.params), jax.tree_util.tree_leaves(b.params)):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    assert [r["fb_loss"] for r in a.metrics] == [r["fb_loss"] for r in b.metrics]
    assert zsbfm.load(str(tmp_path / "a" / "points" / "1")).results["dropped"] == [{"seed": 0, "chunk": 1}]


# --- SIGINT / SIGTERM ------------------------------------------------------------------------

SIGNALLED = TINY + ["steps=200", "chunk_steps=10"]


def _lines(path) -> int:
    try:
        with open(path) as f:
            return sum(1 for line in f if line.endswith("\n"))
    except FileNotFoundError:
        return 0


def test_sigterm_at_a_random_moment_ends_in_one_line_and_the_run_resumes_bit_identically(tmp_path):
    cfg = zsbfm.Config.preset("fourrooms", "fb", num_seeds=2, name="sig").with_overrides(SIGNALLED)
    reference = zsbfm.train(cfg.replace(runs_dir=str(tmp_path / "ref"), checkpoint=False), progress=False)
    runs_dir, run_dir = tmp_path / "runs", tmp_path / "runs" / "sig"
    env = dict(os.environ, JAX_COMPILATION_CACHE_DIR=os.environ["ZSBFM_TEST_XLA_CACHE"],
               JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS="0", JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES="-1")
    proc = subprocess.Popen([sys.executable, "-m", "zsbfm", "train", "--seeds", "2", "--runs-dir", str(runs_dir),
                             "--name", "sig", "--set", *SIGNALLED], cwd=ROOT, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 300
    while _lines(run_dir / "metrics.jsonl") < 1:  # training has begun: the file the run writes
        assert proc.poll() is None and time.time() < deadline, proc.communicate()
        time.sleep(0.02)
    time.sleep(random.uniform(0.0, 0.3))  # a random moment in the chunks that follow
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=300)
    err = err.strip().splitlines()
    assert proc.returncode == 143 and err[-1].startswith("interrupted: SIGTERM: stopped after chunk"), err
    assert not any("Traceback" in line for line in err)
    written = written_chunks(run_dir)
    assert 1 <= written < cfg.num_chunks
    resumed = zsbfm.train(cfg.replace(runs_dir=str(runs_dir)), progress=False)
    assert resumed.results["resumed_from_chunk"] == written
    for a, b in zip(jax.tree_util.tree_leaves(reference.params), jax.tree_util.tree_leaves(resumed.params)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert [r["fb_loss"] for r in resumed.metrics] == [r["fb_loss"] for r in reference.metrics]
    assert resumed.results["train"] == reference.results["train"]


# --- one writer per run directory ---------------------------------------------------------------

# holds the lock of argv[1] until its stdin closes (lock.py alone: it imports nothing of zsbfm's)
HOLDER = """
import importlib.util, sys
spec = importlib.util.spec_from_file_location("lock", sys.argv[2])
lock = importlib.util.module_from_spec(spec); spec.loader.exec_module(lock)
with lock.RunDirLock(sys.argv[1]):
    print("held", flush=True)
    sys.stdin.read()
"""


def test_a_second_writer_gets_one_line_naming_the_holder_and_a_stale_lock_is_taken_over(tmp_path, capsys):
    run_dir = tmp_path / "busy"
    holder = subprocess.Popen([sys.executable, "-c", HOLDER, str(run_dir),
                               os.path.join(ROOT, "src", "zsbfm", "lock.py")],
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(SystemExit) as e:
            main(["train", "--runs-dir", str(tmp_path), "--name", "busy", "--set", *TINY])
        assert e.value.code == 4
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and f"in use by pid {holder.pid} on {socket.gethostname()}" in err[0], err
    finally:
        holder.stdin.close()
        holder.wait(timeout=60)
    assert not (run_dir / LOCK_NAME).exists()  # released at exit

    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()  # its pid no longer runs
    (run_dir / LOCK_NAME).write_text(json.dumps({"host": socket.gethostname(), "pid": gone.pid}))
    with RunDirLock(str(run_dir)):
        assert json.loads((run_dir / LOCK_NAME).read_text())["pid"] == os.getpid()
        assert f"from pid {gone.pid}" in capsys.readouterr().err
        with pytest.raises(RunLocked, match=f"in use by pid {os.getpid()}"):
            RunDirLock(str(run_dir)).acquire()  # held, by a process that runs: refused
    assert not (run_dir / LOCK_NAME).exists()


def test_log_wandb_without_the_package_is_one_line_before_anything_runs(tmp_path, capsys, monkeypatch):
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "wandb" else real(name, *a))
    for argv in (["--log", "wandb"], ["--log", "mlflow"]):
        with pytest.raises(SystemExit) as e:
            main(["train", "--runs-dir", str(tmp_path), "--name", "w", *argv])
        assert e.value.code == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and argv[1] in err[0], err
    assert not (tmp_path / "w").exists()
