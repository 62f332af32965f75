"""Environments behind one functional contract (see `zsbfm.envs.base`)."""

from zsbfm.envs.base import Env, EnvState, index_contexts, num_contexts
from zsbfm.envs.gridworld import GridContext, GridWorld
from zsbfm.envs.pointmass import MazeContext, PointMass

ENV_NAMES = ("doors", "fourrooms", "pointmass")


def make_env(name: str, n_train: int | None = None, episode_len: int | None = None) -> Env:
    """Build an environment by name: "doors", "fourrooms" or "pointmass".

    n_train: number of fixed train layouts (default 20 for the gridworlds, 30 mazes for
    pointmass; the 20 test layouts are fixed per family). episode_len: default 100
    (gridworlds) or 250 (pointmass).
    """
    if name in ("doors", "fourrooms"):
        return GridWorld(name, n_train=n_train or 20, episode_len=episode_len or 100)
    if name == "pointmass":
        return PointMass(n_train=n_train or 30, episode_len=episode_len or 250)
    raise ValueError(f"unknown env {name!r}; available: {', '.join(ENV_NAMES)}")


__all__ = ["Env", "EnvState", "GridContext", "GridWorld", "MazeContext", "PointMass", "ENV_NAMES", "make_env",
           "index_contexts", "num_contexts"]
