"""zsbfm: zero-shot behavioural foundation models under changing dynamics, in JAX.

Public API:
    make_env(name)            environments ("doors", "fourrooms", "pointmass")
    Config                    frozen run configuration with presets (Config.preset)
    train(cfg) -> Run         all seeds of cfg, vmapped, checkpointed, resumable
    evaluate(run, contexts, goals) -> success [seeds, n_contexts, n_goals]
    load(path) -> Run
    make_train(cfg)           the pure pieces of a run (train(key) etc.), for custom loops
"""

from zsbfm.config import Config
from zsbfm.envs import make_env
from zsbfm.evaluate import evaluate
from zsbfm.run import Run, load
from zsbfm.train import make_train, train

__all__ = ["Config", "Run", "make_env", "make_train", "train", "evaluate", "load"]
