"""The compiled training loop end to end: seeds, determinism, traces, resume, I/O."""

import dataclasses
import json
import os
import shutil
import signal

import jax
import numpy as np
import pytest

import zsbfm
from zsbfm.train import TRACE_COUNTS, make_train, seed_keys
from tests.conftest import tiny_config, written_chunks


def leaves(tree):
    return [np.asarray(x) for x in jax.tree_util.tree_leaves(tree)]


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("run")
    before = TRACE_COUNTS["run_chunk"]
    run = zsbfm.train(tiny_config(tmp), progress=False)
    return run, TRACE_COUNTS["run_chunk"] - before


@pytest.mark.plots
def test_end_to_end_writes_results_and_plots(tiny_run):
    run, _ = tiny_run
    run_dir = os.path.join(run.cfg.runs_dir, run.cfg.run_name)
    for f in ("config.json", "results.json", "metrics.jsonl", "metrics.png", "success.png", "value_maps.png"):
        assert os.path.exists(os.path.join(run_dir, f)), f
    with open(os.path.join(run_dir, "results.json")) as f:
        res = json.load(f)
    assert len(res["train"]) == 2 and len(res["test"]) == 2
    assert all(0.0 <= v <= 1.0 for v in res["train"] + res["test"])
    assert np.asarray(res["detail"]["test"]["per_layout"]).shape == (2, 20)
    assert np.asarray(res["detail"]["train"]["per_goal"]).shape == (2, 3)
    assert len(run.metrics) == run.cfg.num_chunks
    assert all(np.isfinite(r["fb_loss"]).all() for r in run.metrics)


def test_chunk_traced_once_for_all_chunks(tiny_run):
    run, traces = tiny_run
    assert run.cfg.num_chunks == 4
    assert traces == 1, f"run_chunk traced {traces} times for {run.cfg.num_chunks} chunks"


def test_vmapped_seeds_differ(tiny_run):
    run, _ = tiny_run
    for leaf in leaves(run.params):
        assert not np.allclose(leaf[0], leaf[1])


def test_same_seed_gives_identical_run(tiny_run, tmp_path):
    run, _ = tiny_run
    again = zsbfm.train(dataclasses.replace(run.cfg, runs_dir=str(tmp_path)), progress=False)
    for a, b in zip(leaves(run.params), leaves(again.params)):
        np.testing.assert_array_equal(a, b)
    assert run.results["train"] == again.results["train"]
    other = zsbfm.train(dataclasses.replace(run.cfg, runs_dir=str(tmp_path), name="s1", seed=1),
                        progress=False)
    assert not np.allclose(leaves(run.params)[0], leaves(other.params)[0])


def test_interrupted_run_resumes_to_the_same_result(tiny_run, tmp_path):
    """SIGINT inside the run (chunk 2's callback) ends it at the next chunk boundary with
    Interrupted (exit code 130 on the command line), chunks 1-2 written; started again, it
    resumes there and ends bit-identical. (SIGTERM at a random moment, from outside: tests/test_guards.py.)"""
    from zsbfm.interrupt import Interrupted

    run, _ = tiny_run
    cfg = dataclasses.replace(run.cfg, runs_dir=str(tmp_path))

    def interrupt_in_chunk_two(chunk, row):
        if chunk == 2:
            os.kill(os.getpid(), signal.SIGINT)

    # whatever SIGINT's handler was (SIG_IGN where pytest runs in a background job), it is back
    before = signal.getsignal(signal.SIGINT)
    with pytest.raises(Interrupted) as e:
        zsbfm.train(cfg, progress=False, callback=interrupt_in_chunk_two)
    assert e.value.exit_code == 130 and str(e.value).startswith("SIGINT: stopped after chunk 2/4")
    assert written_chunks(tmp_path / cfg.run_name) == 2
    assert signal.getsignal(signal.SIGINT) is before  # the handlers are back
    resumed = zsbfm.train(cfg, progress=False)
    assert resumed.results["resumed_from_chunk"] == 2
    for a, b in zip(leaves(run.params), leaves(resumed.params)):
        np.testing.assert_array_equal(a, b)
    assert [r["fb_loss"] for r in resumed.metrics] == [r["fb_loss"] for r in run.metrics]


@pytest.fixture(scope="module")
def encoder_run(tmp_path_factory):
    """A tiny staged Belief-FB encoder run (2 encoder chunks, 1 FB chunk) and the config of a
    run that may start from it: h_train_true and more steps (FB-phase fields)."""
    tmp = tmp_path_factory.mktemp("reuse")
    base = tiny_config(tmp, algo="bfb", num_seeds=1, h_from="context", enc_steps=20, steps=30, name="enc")
    enc = zsbfm.train(base, progress=False)
    return enc, dataclasses.replace(base, name="f", h_train_true=True, steps=40), tmp


def test_encoder_from_copies_the_end_of_the_encoder_phase(encoder_run, tmp_path):
    """encoder_checkpoint finds chunk 2 (enc_steps / chunk_steps) of the encoder run;
    seed_from_encoder_run copies its checkpoint and the metrics rows up to it, once."""
    from zsbfm.encoder_reuse import encoder_checkpoint, seed_from_encoder_run

    enc, cfg, tmp = encoder_run
    enc_dir = str(tmp / "runs" / "enc")
    folder, chunk = encoder_checkpoint(cfg, enc_dir)
    assert (folder, chunk) == (os.path.join(enc_dir, "checkpoints", "2"), 2)
    assert seed_from_encoder_run(str(tmp_path), enc_dir, folder, chunk)
    assert os.listdir(tmp_path / "checkpoints") == ["2"]
    assert sorted(os.listdir(tmp_path / "checkpoints" / "2")) == sorted(os.listdir(folder))
    with open(tmp_path / "metrics.jsonl") as f:
        assert [json.loads(line) for line in f] == enc.metrics[:2]
    assert not seed_from_encoder_run(str(tmp_path), enc_dir, folder, chunk)  # it has a checkpoint now


@pytest.mark.slow
def test_encoder_from_equals_the_run_trained_from_scratch(encoder_run):
    """A run started from the encoder run's encoder phase (train(encoder_from=)) and the same
    config trained from scratch end with the same parameters, metrics and scores."""
    enc, cfg, tmp = encoder_run
    reused = zsbfm.train(cfg, progress=False, encoder_from=str(tmp / "runs" / "enc"))
    scratch = zsbfm.train(dataclasses.replace(cfg, name="scratch"), progress=False)
    assert reused.results["resumed_from_chunk"] == 2 and scratch.results["resumed_from_chunk"] == 0
    assert reused.metrics[:2] == enc.metrics[:2]
    for a, b in zip(leaves(reused.params), leaves(scratch.params)):
        np.testing.assert_array_equal(a, b)
    for key in ("enc_mse", "fb_loss"):
        assert [r.get(key) for r in reused.metrics] == [r.get(key) for r in scratch.metrics]
    assert reused.results["test"] == scratch.results["test"]


def test_encoder_from_refuses_another_encoder_phase_before_writing(encoder_run, tmp_path):
    """Another learning rate, no run, a non-belief run, or no checkpoint at the end of the
    encoder phase: a ValueError that names it, and no run directory."""
    _, cfg, tmp = encoder_run
    enc_dir, cfg = str(tmp / "runs" / "enc"), dataclasses.replace(cfg, name="other")
    with pytest.raises(ValueError, match=r"encoder_from=.*'lr': \(0.0003, 0.001\)"):
        zsbfm.train(dataclasses.replace(cfg, lr=1e-3), progress=False, encoder_from=enc_dir)
    with pytest.raises(ValueError, match="encoder_from=.*no run there"):
        zsbfm.train(cfg, progress=False, encoder_from=str(tmp / "none"))
    with pytest.raises(ValueError, match=r"encoder_from=.*needs a staged belief run"):
        zsbfm.train(tiny_config(tmp, name="other"), progress=False, encoder_from=enc_dir)
    pruned = str(tmp_path / "pruned")  # a copy: the module's encoder run stays whole
    shutil.copytree(enc_dir, pruned)
    shutil.rmtree(os.path.join(pruned, "checkpoints", "2"))
    with pytest.raises(ValueError, match=r"no checkpoint at chunk 2, .* keeps \[3\]"):
        zsbfm.train(cfg, progress=False, encoder_from=pruned)
    assert not os.path.exists(tmp / "runs" / "other")


def test_other_config_in_same_directory_is_refused(tiny_run):
    run, _ = tiny_run
    with pytest.raises(ValueError, match="different config"):
        zsbfm.train(dataclasses.replace(run.cfg, lr=1e-2), progress=False)


def test_pure_train_program_matches_host_driver(tiny_run):
    """jit(vmap(train)) over seed keys: the one-program form gives the driver's result."""
    run, _ = tiny_run
    trainer = make_train(run.cfg)
    carry, metrics, success = jax.jit(jax.vmap(trainer.train))(seed_keys(run.cfg))
    params = trainer.agent.eval_params(carry.agent_state)
    for a, b in zip(leaves(run.params), leaves(params)):
        np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-5)
    assert metrics["fb_loss"].shape == (2, run.cfg.num_chunks)
    assert success["test"].shape == (2, 20, 3)


def test_evaluate_contract_and_load(tiny_run):
    run, _ = tiny_run
    env = zsbfm.make_env("fourrooms", n_train=run.cfg.n_train_layouts)
    ctxs = env.contexts("test")
    goals = np.tile(np.array([[[8.0, 8.0], [2.0, 8.0]]]), (20, 1, 1))
    success = zsbfm.evaluate(run, contexts=ctxs, goals=goals)
    assert success.shape == (2, 20, 2) and success.dtype == bool
    loaded = zsbfm.load(os.path.join(run.cfg.runs_dir, run.cfg.run_name))
    assert loaded.cfg == run.cfg and loaded.results == run.results
    for a, b in zip(leaves(run.params), leaves(loaded.params)):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(np.asarray(zsbfm.evaluate(loaded, contexts=ctxs, goals=goals)),
                                  np.asarray(success))
    with pytest.raises(ValueError, match="goals must be"):
        zsbfm.evaluate(run, contexts=ctxs, goals=goals[:, :, :1])


@pytest.mark.parametrize("field,value,match", [
    ("env", "humanoid", "Config.env='humanoid'"),
    ("algo", "sac", "Config.algo='sac'"),
    ("batch_size", 0, "Config.batch_size=0"),
    ("steps", 15, "a multiple of chunk_steps"),
    ("context_len", 101, "Config.context_len=101"),
    ("gamma", 1.0, "Config.gamma=1.0"),
    ("f_hidden", (), "Config.f_hidden=()"),
    ("n_train_layouts", -1, "Config.n_train_layouts=-1"),
    ("obs_encoding", "cell", "Config.obs_encoding='cell'"),
])
def test_invalid_config_raises_naming_the_field(field, value, match):
    with pytest.raises(ValueError, match=match.replace("(", r"\(").replace(")", r"\)")):
        zsbfm.Config(**{field: value})


def test_doors_layout_limit_is_checked():
    with pytest.raises(ValueError, match="at most 29 for doors"):
        zsbfm.Config.preset("doors", "fb", n_train_layouts=30)


def test_presets_are_labelled_and_overrides_parse():
    cpu = zsbfm.Config.preset("fourrooms", "fb")
    paper = zsbfm.Config.preset("fourrooms", "fb", size="paper")
    assert cpu.size == "cpu" and paper.size == "paper"
    assert paper.d == 100 and paper.batch_size == 1024 and paper.steps == 1_000_000
    cfg = cpu.with_overrides(["steps=2000", "lr=1e-3", "f_hidden=64,64", "checkpoint=false"])
    assert (cfg.steps, cfg.lr, cfg.f_hidden, cfg.checkpoint) == (2000, 1e-3, (64, 64), False)
    with pytest.raises(ValueError, match="unknown Config field 'lrr'"):
        cpu.with_overrides(["lrr=1"])
    assert zsbfm.Config.from_dict(json.loads(cfg.to_json())) == cfg


def test_cli_train_runs(tmp_path, capsys):
    from zsbfm.cli import main

    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    # the widths of tests/test_cli.py's runs (official protocol only), so XLA's cache can
    # serve whichever of them compiles second
    main(["train", "--env", "doors", "--seeds", "2", "--runs-dir", str(tmp_path), "--name", "cli",
          "--set", "steps=10", "chunk_steps=5", "n_train_layouts=3", "episodes_per_layout=10",
          "d=8", "f_pre_hidden=16", "f_pre_out=16", "f_hidden=16", "b_hidden=16", "batch_size=16",
          "eval_episode_len=10", "context_len=10", "eval_protocols=official", "--log", "tensorboard"])
    out = capsys.readouterr().out
    assert "test  success" in out
    assert os.path.exists(tmp_path / "cli" / "results.json")
    events = EventAccumulator(str(tmp_path / "cli" / "tensorboard"))  # --log tensorboard
    events.Reload()
    losses = [json.loads(line)["fb_loss"][0] for line in open(tmp_path / "cli" / "metrics.jsonl")]
    assert [(e.step, e.value) for e in events.Scalars("fb_loss/seed0")] == [(5, pytest.approx(losses[0])),
                                                                           (10, pytest.approx(losses[1]))]
    with pytest.raises(SystemExit) as e:
        main(["train", "--env", "humanoid"])
    assert e.value.code == 2
