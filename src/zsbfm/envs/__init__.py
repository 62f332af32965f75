"""Environments behind one functional contract (see `zsbfm.envs.base`)."""

from zsbfm.envs.base import Env, EnvState, index_contexts, num_contexts
from zsbfm.envs.gridworld import GridContext, GridWorld

ENV_NAMES = ("doors", "fourrooms")


def make_env(name: str, n_train: int = 20, episode_len: int = 100) -> Env:
    """Build an environment by name: "doors" or "fourrooms".

    n_train: number of fixed train layouts (the 20 test layouts are fixed per family).
    """
    if name in ("doors", "fourrooms"):
        return GridWorld(name, n_train=n_train, episode_len=episode_len)
    raise ValueError(f"unknown env {name!r}; available: {', '.join(ENV_NAMES)}")


__all__ = ["Env", "EnvState", "GridContext", "GridWorld", "ENV_NAMES", "make_env",
           "index_contexts", "num_contexts"]
