"""Sweeps through vmap, evaluation protocols and learning curves."""

import dataclasses
import json
import os
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import zsbfm
from zsbfm.envs import index_contexts
from zsbfm.sweep import parse_grid, sweep
from zsbfm.train import TRACE_COUNTS

from conftest import strict_lines, tiny_config


def test_two_by_two_sweep_equals_four_runs_and_compiles_once(tmp_path):
    """Every point of a 2 x 2 sweep (2 seeds each, one program) equals the separate run of
    that point's Config: same scores, same final losses (every row got its own settings;
    the last point, which differs from the first in both settings, is run separately)."""
    cfg = tiny_config(tmp_path, steps=20, eval_protocols="official", name="sw")
    grid = parse_grid(cfg, ["lr=1e-4,1e-2", "tau=0.05,0.5"])
    before = TRACE_COUNTS["run_chunk"]
    seen = []
    res = sweep(cfg, grid, progress=False, callback=lambda chunk, row: seen.append((chunk, row)))
    assert TRACE_COUNTS["run_chunk"] - before == 1, "a sweep of scalar settings is one program"
    # the callback sees every chunk of every point, with that point's losses per seed
    assert [(c, r["point"]) for c, r in seen] == [(c, p) for c in (1, 2) for p in range(4)]
    assert all(len(r["fb_loss"]) == 2 and r["label"] == res.points[r["point"]]["label"] for _, r in seen)
    assert [p["label"] for p in res.points] == ["lr=0.0001 tau=0.05", "lr=0.0001 tau=0.5",
                                               "lr=0.01 tau=0.05", "lr=0.01 tau=0.5"]
    rows = [json.loads(line) for line in open(tmp_path / "runs" / "sw" / "g0" / "metrics.jsonl")]
    losses = np.asarray(rows[-1]["fb_loss"]).reshape(4, 2)               # [point, seed]
    for i, p in enumerate(res.points):
        if i != 3:  # the point that differs from the first in both settings
            continue
        single = zsbfm.train(dataclasses.replace(cfg, name=f"single{i}", **p["settings"]), progress=False)
        assert p["train"] == single.results["train"] and p["test"] == single.results["test"]
        np.testing.assert_allclose(losses[i], single.metrics[-1]["fb_loss"], rtol=1e-4)
    assert len({round(float(v), 4) for v in losses[:, 0]}) == 4
    for f in ("sweep.json", "sweep.md", "sweep.png"):
        assert os.path.exists(tmp_path / "runs" / "sw" / f)


def test_shape_changing_fields_compile_one_program_each(tmp_path):
    cfg = tiny_config(tmp_path, steps=10, eval_protocols="official", name="sw3", num_seeds=1)
    before = TRACE_COUNTS["run_chunk"]
    res = sweep(cfg, parse_grid(cfg, ["d=4,8", "lr=1e-3,2e-3"]), progress=False)
    assert TRACE_COUNTS["run_chunk"] - before == 2
    assert [p["settings"] for p in res.points] == [{"d": 4, "lr": 1e-3}, {"d": 4, "lr": 2e-3},
                                                  {"d": 8, "lr": 1e-3}, {"d": 8, "lr": 2e-3}]


@pytest.mark.parametrize("item,match", [
    ("lr=1e-3,-1", "Config.lr=-1"),
    ("gamma=0.9,1.5", "Config.gamma=1.5"),
    ("lrr=1", "unknown Config field 'lrr'"),
    ("lr", "must look like field=v1,v2"),
    ("d=8,x", "cannot parse 'x'"),
])
def test_bad_grid_values_fail_like_set(item, match):
    cfg = zsbfm.Config.preset("fourrooms", "oracle")
    with pytest.raises(ValueError, match=match):
        parse_grid(cfg, [item])


def test_cli_sweep_reports_bad_values_in_one_line(capsys):
    from zsbfm.cli import main

    with pytest.raises(SystemExit) as e:
        main(["sweep", "--grid", "lr=1e-3,-2"])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "Config.lr=-2" in err[0]


def test_protocols_of_the_gridworld():
    env = zsbfm.make_env("fourrooms")
    ctx = index_contexts(env.contexts("test"), 3)
    walls = np.asarray(ctx.walls)
    starts, goals, valid = env.eval_tasks(ctx, "paper", jax.random.PRNGKey(0))
    assert goals.tolist() == [[8, 8], [2, 8], [8, 2]] and starts.tolist() == [[1, 1]] * 3
    starts, goals, valid = env.eval_tasks(ctx, "dense", jax.random.PRNGKey(0))
    assert int(valid.sum()) == int((~walls).sum()) - 1          # every free cell but the start
    g = np.asarray(goals)[np.asarray(valid)].astype(int)
    assert not walls[g[:, 1], g[:, 0]].any()
    starts, goals, valid = env.eval_tasks(ctx, "random_start", jax.random.PRNGKey(1))
    s, g = np.asarray(starts).astype(int), np.asarray(goals).astype(int)
    assert len(g) == 20 and {tuple(x) for x in g} == {(2, 2), (8, 8), (2, 8), (8, 2)}
    assert not walls[s[:, 1], s[:, 0]].any() and not (s == g).all(1).any()
    assert len({tuple(x) for x in s}) > 5                          # random, not one cell
    with pytest.raises(ValueError, match="unknown protocol"):
        env.eval_tasks(ctx, "nope", jax.random.PRNGKey(0))


@pytest.mark.plots
def test_learning_curve_logs_every_protocol_and_ends_at_the_results(tmp_path):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    from zsbfm.loggers import TensorBoardLogger

    cfg = tiny_config(tmp_path, steps=40, eval_every=2, name="curve", eval_protocols="all")
    before = TRACE_COUNTS["evaluate_protocols"]
    seen = []
    with TensorBoardLogger(str(tmp_path / "tb")) as tb:
        run = zsbfm.train(cfg, progress=False, callback=lambda chunk, row: (seen.append((chunk, row)), tb(chunk, row)))
    assert TRACE_COUNTS["evaluate_protocols"] - before == 1, "the curve's evaluation compiles once"
    # the callback sees every chunk's row, as metrics.jsonl holds it: losses per seed, and the
    # learning-curve points and cumulative FLOPs where evaluated
    assert [c for c, _ in seen] == [1, 2, 3, 4] and [r for _, r in seen] == run.metrics
    assert ["flops" in r and "eval/test/dense" in r for _, r in seen] == [False, True, False, True]
    # the event file reads back with TensorBoard's own reader and holds the run's numbers
    events = EventAccumulator(str(tmp_path / "tb"))
    events.Reload()
    for name, steps in (("fb_loss/seed1", [10, 20, 30, 40]), ("eval/train/dense/seed0", [20, 40]), ("flops", [20, 40])):
        key, seed = (name.rsplit("/seed", 1) + [None])[:2]
        logged = [m for m in run.metrics if key in m]
        assert [e.step for e in events.Scalars(name)] == steps
        expected = [m[key] if seed is None else m[key][int(seed)] for m in logged]
        np.testing.assert_allclose([e.value for e in events.Scalars(name)], expected, rtol=1e-6)
    evals = [m for m in run.metrics if "eval/train/dense" in m]
    assert [m["step"] for m in evals] == [20, 40]
    assert all(m["flops"] > 0 for m in evals) and evals[1]["flops"] == pytest.approx(2 * evals[0]["flops"])
    for protocol in ("paper", "dense", "random_start"):
        for split in ("train", "test"):
            assert run.results["protocols"][protocol][split] == evals[-1][f"eval/{split}/{protocol}"]
    # the official protocol's curve point is the official score
    np.testing.assert_allclose(run.results["train"], run.results["protocols"]["paper"]["train"], atol=1e-4)
    score, valid = zsbfm.evaluate(run, split="train", protocol="dense")
    from zsbfm.evaluate import protocol_score

    np.testing.assert_allclose(np.asarray(protocol_score(score, valid)), run.results["protocols"]["dense"]["train"],
                               atol=1e-4)
    assert os.path.exists(tmp_path / "runs" / "curve" / "curves.png")


# rfb, oracle and lap evaluate through the paths bfb, bfb and hilp cover: in `make test-all`
@pytest.mark.parametrize("algo", ["fb", "bfb", "hilp", "random"] + [pytest.param(a, marks=pytest.mark.slow)
                                                                   for a in ("rfb", "oracle", "lap")])
def test_evaluate_reproduces_the_run_results(tmp_path, algo):
    extra = dict(steps=20, enc_steps=10) if algo in ("bfb", "rfb") else dict(steps=20)
    # fb: every protocol, scored at the end only (eval_every=0): the official one from the
    # official scores, the others by their own rollouts
    protocols = "all" if algo == "fb" else "official"
    cfg = tiny_config(tmp_path, algo=algo, eval_protocols=protocols, name=f"ev-{algo}", **extra)
    run = zsbfm.train(cfg, progress=False)
    if algo == "bfb":  # each chunk's line holds the metrics its phase computed, as strict JSON
        encoder, fb = strict_lines(tmp_path / "runs" / cfg.run_name / "metrics.jsonl")
        assert {"enc_mse", "enc_kl", "h_norm"} <= set(encoder) and "fb_loss" not in encoder
        assert "fb_loss" in fb and not {"enc_mse", "enc_kl", "h_norm"} & set(fb)
    loaded = zsbfm.load(os.path.join(cfg.runs_dir, cfg.run_name))
    for split in ("train", "test"):
        again = np.asarray(zsbfm.evaluate(loaded, split=split), np.float32).mean((1, 2))
        np.testing.assert_allclose(again, run.results[split], atol=1e-6)
        np.testing.assert_allclose(run.results["protocols"]["paper"][split], run.results[split], atol=1e-4)
    if algo == "fb":
        from zsbfm.evaluate import protocol_score

        assert set(run.results["protocols"]) == {"paper", "dense", "random_start"}
        for protocol in ("dense", "random_start"):
            score, valid = zsbfm.evaluate(loaded, split="test", protocol=protocol)
            np.testing.assert_allclose(np.asarray(protocol_score(score, valid)),
                                       run.results["protocols"][protocol]["test"], atol=1e-4)


def test_curves_last_mean_averages_each_seeds_last_evaluations_then_the_seeds():
    """experiments/curves.py --last k: each seed's mean over its last k evaluations, then the
    mean and standard error over seeds (hand numbers)."""
    sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "experiments"))
    from curves import last_mean

    scores = np.array([[0.0, 0.0, 0.0], [0.9, 0.9, 0.9], [0.6, 0.7, 0.8], [0.8, 0.7, 1.0]])  # [T=4, S=3]
    mean, se, per_seed = last_mean({"scores": {"train/paper": scores}}, "train/paper", 2)
    np.testing.assert_allclose(per_seed, [0.7, 0.7, 0.9])
    assert mean == pytest.approx(23 / 30)
    assert se == pytest.approx(np.sqrt(((0.7 - 23 / 30) ** 2 * 2 + (0.9 - 23 / 30) ** 2) / 2) / np.sqrt(3))
    one = last_mean({"scores": {"train/paper": scores[:, :1]}}, "train/paper", 10)  # k past the start: all
    assert one[0] == pytest.approx(0.575) and one[1] == 0.0
