import atexit
import json
import os
import shutil
import tempfile

os.environ.setdefault("JAX_PLATFORMS", "cpu")
# Tests spend their time compiling tiny programs, not running them: XLA's CPU backend without
# its expensive LLVM passes compiles a tiny FB run ~25-35% faster (measured on the 2-core CPU)
# and computes the same maths. Set before jax is imported; a subprocess the tests start
# inherits it unless it sets XLA_FLAGS itself.
os.environ.setdefault("XLA_FLAGS", "--xla_backend_optimization_level=0 --xla_llvm_disable_expensive_passes=true")

import jax  # noqa: E402
import orbax.checkpoint as ocp  # noqa: E402
import pytest  # noqa: E402

import zsbfm  # noqa: E402

# Many tests train the same tiny program again (another seed, a resumed run, a second
# directory). Each zsbfm.train builds a new closure, so jit traces it again; XLA's
# persistent cache then returns the executable of an identical program instead of
# compiling it anew (~20 s -> ~3 s per repeat on the 2-core CPU). Tracing is unchanged, so
# the trace-count tests still count. A fresh directory per session: nothing carries over
# between test runs. `make test` runs pytest-xdist workers (`-n auto`): the controller makes
# the directory and the workers inherit it through the environment, so one worker's compile
# serves the other; only the process that made it removes it.
_CACHE_DIR = os.environ.get("ZSBFM_TEST_XLA_CACHE")
if _CACHE_DIR is None:
    _CACHE_DIR = tempfile.mkdtemp(prefix="zsbfm-xla-cache-")
    os.environ["ZSBFM_TEST_XLA_CACHE"] = _CACHE_DIR
    atexit.register(shutil.rmtree, _CACHE_DIR, ignore_errors=True)
jax.config.update("jax_compilation_cache_dir", _CACHE_DIR)
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0)
jax.config.update("jax_persistent_cache_min_entry_size_bytes", -1)


# The few tests that run hundreds of updates compile those loops with XLA's full
# optimisation instead: at level 0 a 600-step encoder pre-training ran 37 s, at level 3 15 s
# (+1.5 s of compile; 2-core CPU).
OPTIMISED = {"xla_backend_optimization_level": 3, "xla_llvm_disable_expensive_passes": False}


def jit_optimised(fn, **kwargs):
    """jax.jit(fn) compiled with XLA's full optimisation (for a test's long training loop)."""
    return jax.jit(fn, compiler_options=OPTIMISED, **kwargs)


@pytest.fixture(autouse=True)
def _skip_run_plots(request, monkeypatch):
    """zsbfm.train draws a run's PNGs after training (matplotlib: seconds per run); a test
    that checks only numbers skips them, a test marked `plots` (or a run made by a module-
    or session-scoped fixture, set up before this) draws them as a user's run does."""
    if "plots" not in request.keywords:
        monkeypatch.setattr("zsbfm.plots.plot_run", lambda run, run_dir: None)


def tiny_config(tmp_path, algo="fb", env="fourrooms", **overrides):
    """A config of `algo` on `env` (FB on fourrooms by default) small enough for a test (seconds)."""
    base = dict(num_seeds=2, n_train_layouts=4, episodes_per_layout=20, d=8,
                f_pre_hidden=(16,), f_pre_out=16, f_hidden=(32,), b_hidden=(16,), batch_size=32,
                # belief methods: a one-block encoder (each block is compiled code of its own)
                enc_layers=1, enc_embed=8, enc_heads=2, enc_mlp=16, pred_hidden=(16,),
                steps=40, chunk_steps=10, eval_episode_len=20, context_len=20, eval_protocols="official",
                runs_dir=str(tmp_path / "runs"), name="tiny")
    base.update(overrides)
    return zsbfm.Config.preset(env, algo, **base)


@pytest.fixture
def tiny_cfg(tmp_path):
    return tiny_config(tmp_path)


def strict_lines(path) -> list[dict]:
    """metrics.jsonl read with a JSON parser that rejects NaN and Infinity."""
    def reject(token):
        raise ValueError(f"non-standard JSON constant {token} in {path}")

    with open(path) as f:
        return [json.loads(line, parse_constant=reject) for line in f]


def written_chunks(run_dir) -> int:
    """The chunks an interrupted run wrote: metrics lines (strict JSON) and checkpoints agree,
    no results, no lock left."""
    rows = strict_lines(run_dir / "metrics.jsonl")
    assert [r["chunk"] for r in rows] == list(range(1, len(rows) + 1))
    assert ocp.CheckpointManager(str(run_dir / "checkpoints")).latest_step() == len(rows)
    assert not (run_dir / "results.json").exists() and not (run_dir / ".lock").exists()
    return len(rows)
