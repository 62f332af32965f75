"""zsbfm: zero-shot behavioural foundation models under changing dynamics, in JAX.

Public API:
    make_env(name)            environments ("doors", "fourrooms", "pointmass")
    Config                    frozen run configuration with presets (Config.preset)
    train(cfg) -> Run         all seeds of cfg, vmapped, checkpointed, resumable
    evaluate(run, contexts, goals) -> success [seeds, n_contexts, n_goals]
    load(path) -> Run
    make_train(cfg)           the pure pieces of a run (train(key) etc.), for custom loops
"""

from zsbfm.cpu_tuning import limit_blas_threads, unroll_threefry

limit_blas_threads()  # before anything loads scipy's LAPACK: see zsbfm/cpu_tuning.py
unroll_threefry()  # the same random bits without a loop per draw: see zsbfm/cpu_tuning.py

from zsbfm.config import Config  # noqa: E402
from zsbfm.envs import make_env  # noqa: E402
from zsbfm.evaluate import evaluate  # noqa: E402
from zsbfm.run import Run, load  # noqa: E402
from zsbfm.train import make_train, train  # noqa: E402

__all__ = ["Config", "Run", "make_env", "make_train", "train", "evaluate", "load"]
