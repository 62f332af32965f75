"""What a user meets on the command line: data sources, evaluate, help and errors."""

import json
import os

import jax
import numpy as np
import pytest

import zsbfm
from zsbfm.cli import main
from zsbfm.data import load_dataset
from zsbfm.train import make_train

from conftest import tiny_config

TINY = ["d=8", "f_pre_hidden=16", "f_pre_out=16", "f_hidden=16", "b_hidden=16", "batch_size=16",
        "eval_episode_len=10", "context_len=10", "eval_protocols=official"]


def test_collect_then_train_on_the_saved_dataset(tmp_path, capsys):
    path = str(tmp_path / "doors.npz")
    main(["collect", "--env", "doors", "--n-train", "3", "--episodes-per-layout", "10", "--out", path])
    main(["train", "--env", "doors", "--seeds", "2", "--runs-dir", str(tmp_path), "--name", "from-file",
          "--dataset", path, "--set", "steps=10", "chunk_steps=5", "n_train_layouts=3",
          "episodes_per_layout=10", *TINY])
    assert "test  success" in capsys.readouterr().out
    run = zsbfm.load(str(tmp_path / "from-file"))
    assert run.cfg.dataset == path
    trainer = make_train(run.cfg)
    saved = load_dataset(path)
    for seed in range(2):  # every seed trains on the file, not on data of its own key
        carry = trainer.init(jax.random.PRNGKey(seed))
        np.testing.assert_array_equal(np.asarray(trainer.collect_data(carry).obs), np.asarray(saved.obs))


def test_a_dataset_that_does_not_fit_is_one_line(tmp_path, capsys):
    path = str(tmp_path / "doors.npz")
    main(["collect", "--env", "doors", "--n-train", "3", "--episodes-per-layout", "10", "--out", path])
    capsys.readouterr()
    with pytest.raises(SystemExit) as e:
        main(["train", "--env", "doors", "--runs-dir", str(tmp_path), "--dataset", path,
              "--set", "n_train_layouts=4", "episodes_per_layout=10", *TINY])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "episodes_per_layout=10" in err[0] and path in err[0]


def test_evaluate_takes_the_run_directory_and_reports_its_numbers(tmp_path, capsys):
    cfg = tiny_config(tmp_path, name="ev", eval_protocols="official")
    run = zsbfm.train(cfg, progress=False)
    main(["evaluate", os.path.join(cfg.runs_dir, "ev"), "--split", "test"])
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    np.testing.assert_allclose(out["success_per_seed"], run.results["test"], atol=1e-4)
    with pytest.raises(SystemExit) as e:
        main(["evaluate", str(tmp_path / "missing")])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not a zsbfm run directory" in err[0]


def test_evaluate_over_draws_reports_the_own_draw_and_the_spread(capsys):
    """--draws 3: the run's own draw (its reported numbers) plus 2 fresh ones; the mean and
    standard error are those of the three."""
    fixture = os.path.join(os.path.dirname(__file__), "fixtures", "fb_c971d54")  # a 2-seed FB run
    run = zsbfm.load(fixture)
    main(["evaluate", fixture, "--split", "test", "--protocol", "random_start", "--draws", "3"])
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    own = run.results["protocols"]["random_start"]["test"]
    np.testing.assert_allclose(out["success_per_seed"], own, atol=1e-4)
    assert out["draws"] == 3 and len(out["se_per_seed"]) == len(out["mean_over_draws_per_seed"]) == 2
    assert max(out["se_per_seed"]) > 0  # the fresh draws differ from the own one
    with pytest.raises(SystemExit) as e:
        main(["evaluate", fixture, "--draws", "0"])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "draws=0" in err[0]


def test_help_names_the_module_and_has_plain_flags(capsys):
    with pytest.raises(SystemExit):
        main(["train", "--help"])
    out = capsys.readouterr().out
    assert "python -m zsbfm train" in out and "__main__.py" not in out
    assert "--no-resume" in out and "--no-no-resume" not in out


@pytest.mark.parametrize("command", ["train", "sweep", "collect"])
def test_help_names_every_value_the_code_accepts(command, capsys):
    """Every --env, --algo and --size value Config accepts is named in the command's help."""
    from zsbfm.config import ENVS, SIZES
    from zsbfm.names import ALGOS

    with pytest.raises(SystemExit):
        main([command, "--help"])
    out = " ".join(capsys.readouterr().out.replace("│", " ").split())  # the help box, unwrapped
    accepted = {"env": ENVS, "algo": ALGOS if command != "collect" else (),
                "size": SIZES if command != "collect" else ()}
    for flag, values in accepted.items():
        for value in values:
            assert value in out.split(f"--{flag} STR")[1].split(" --")[0], (flag, value)


def test_rerunning_a_finished_run_keeps_its_training_time(tmp_path):
    cfg = tiny_config(tmp_path, name="again", eval_protocols="official")
    first = zsbfm.train(cfg, progress=False)
    again = zsbfm.train(cfg, progress=False)
    assert again.results["resumed_from_chunk"] == cfg.num_chunks
    assert again.results["wall_time_s"]["train"] == first.results["wall_time_s"]["train"]
    assert again.results["train"] == first.results["train"]


def test_shortening_a_belief_preset_is_one_edit():
    cfg = zsbfm.Config.preset("fourrooms", "rfb", steps=2000)
    assert cfg.enc_steps == 1000 and cfg.steps == 2000           # the preset's share, whole chunks
    cfg = zsbfm.Config.preset("fourrooms", "bfb", steps=300, chunk_steps=100)
    assert cfg.enc_steps == 100
    assert zsbfm.Config.preset("fourrooms", "bfb", steps=300, chunk_steps=100, enc_steps=200).enc_steps == 200
