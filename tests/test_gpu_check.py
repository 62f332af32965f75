"""experiments/gpu_check.sh runs its GPU path at tiny sizes on a CPU."""

import json
import os
import subprocess
import sys

import pytest

ROOT = os.path.join(os.path.dirname(__file__), "..")


@pytest.mark.slow  # ~60 s (a subprocess compiling two paper-layout programs): `make test-all`
def test_gpu_check_runs_tiny_on_cpu(tmp_path):
    out = tmp_path / "gpu_check.json"
    env = dict(os.environ, JAX_PLATFORMS="cpu", BUDGET="1", GPU_CHECK_OUT=str(out), PY=sys.executable)
    proc = subprocess.run(["bash", os.path.join(ROOT, "experiments", "gpu_check.sh")], env=env,
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    res = json.loads(out.read_text())
    assert res["backend"] == "cpu" and [(r["algo"], r["config"], r["seeds"]) for r in res["results"]] == [
        ("fb", "paper (tiny)", 1), ("bfb", "paper (tiny)", 1), ("bfb", "authors (tiny)", 3),
        ("rfb", "authors (tiny)", 3), ("fb", "authors (tiny)", 3)]
    for r in res["results"]:
        row = r["curve"][0]
        assert row["updates"] == 10 and row["updates_per_s"] > 0 and len(row["train/paper_per_seed"]) == r["seeds"]
        assert 0 <= row["train/dense"] <= 1 and row["gflop_per_update"] > 0
        # the chunk's own phase's losses only: a belief check's first chunk trains the encoder
        assert ("enc_mse" in row) == (r["encoder_steps"] > 0) and ("fb_loss" in row) == (r["encoder_steps"] == 0)


@pytest.mark.slow  # ~40 s: `make test-all`
def test_gpu_check_applies_overrides_and_its_curves_plot(tmp_path):
    out, png = tmp_path / "gpu_check.json", tmp_path / "curves.png"
    env = dict(os.environ, JAX_PLATFORMS="cpu", BUDGET="1", GPU_CHECK_OUT=str(out), PY=sys.executable)
    proc = subprocess.run(["bash", os.path.join(ROOT, "experiments", "gpu_check.sh"), "--checks", "oracle:authors:2",
                           "--set", "twin_target=mean"], env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    (r,) = json.loads(out.read_text())["results"]
    assert r["overrides"] == ["twin_target=mean"] and r["encoder_steps"] == 0
    row = r["curve"][0]
    assert {"fb_loss", "M_diag", "M_offdiag", "M_head_gap"} <= set(row) and row["M_head_gap"] >= 0
    proc = subprocess.run([sys.executable, os.path.join(ROOT, "experiments", "gpu_curves.py"), str(out), "--out", str(png),
                           "--ref", "recorded:20000=0.73"], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert png.stat().st_size > 0
