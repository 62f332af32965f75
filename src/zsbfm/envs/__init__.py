"""Environments behind one functional contract (see `zsbfm.envs.base`)."""

from zsbfm.envs.antwind import AntWind, WindContext
from zsbfm.envs.base import Env, EnvState, index_contexts, num_contexts
from zsbfm.envs.gridworld import GridContext, GridWorld
from zsbfm.envs.pointmass import MazeContext, PointMass

ENV_NAMES = ("doors", "fourrooms", "pointmass", "antwind")


def make_env(name: str, n_train: int | None = None, episode_len: int | None = None) -> Env:
    """Build an environment by name: "doors", "fourrooms", "pointmass" or "antwind".

    n_train: number of fixed train layouts (default 20 for the gridworlds, 30 mazes for
    pointmass; the 20 test layouts are fixed per family; antwind's 15 train / 5 test winds
    are fixed). episode_len: default 100 (gridworlds), 250 (pointmass) or 256 (antwind).
    AntWind comes without an expert (uniform behaviour); `make_env_for(cfg)` attaches it.
    """
    if name in ("doors", "fourrooms"):
        return GridWorld(name, n_train=n_train or 20, episode_len=episode_len or 100)
    if name == "pointmass":
        return PointMass(n_train=n_train or 30, episode_len=episode_len or 250)
    if name == "antwind":
        if n_train not in (None, 15):
            raise ValueError(f"antwind has 15 fixed train winds, got n_train={n_train}")
        return AntWind(episode_len=episode_len or 256)
    raise ValueError(f"unknown env {name!r}; available: {', '.join(ENV_NAMES)}")


def make_env_for(cfg, progress: bool = True) -> Env:
    """The environment of a Config, ready to collect data: for antwind with its behaviour
    policy (the wind-aware expert, trained or read from cfg.data_dir; see zsbfm.data.expert)."""
    if cfg.env == "antwind":
        from zsbfm.data.expert import antwind_env

        return antwind_env(cfg, progress)
    return make_env(cfg.env, n_train=cfg.n_train_layouts, episode_len=cfg.episode_len)


__all__ = ["AntWind", "WindContext", "make_env_for", "Env", "EnvState", "GridContext", "GridWorld", "MazeContext", "PointMass", "ENV_NAMES", "make_env",
           "index_contexts", "num_contexts"]
