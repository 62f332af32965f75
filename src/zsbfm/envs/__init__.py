"""Environments behind one functional contract (`zsbfm.envs.base`) and one registry
(`zsbfm.envs.registry`): every caller builds an environment with `make_env(name, ...)`.
Importing this package registers the built-in environments."""

from zsbfm.envs import gridworld, pointmass, antwind  # noqa: F401, I001  (each registers itself, in this order)
from zsbfm.envs.antwind import AntWind, WindContext
from zsbfm.envs.base import Env, EnvBase, EnvState, index_contexts, num_contexts
from zsbfm.envs.gridworld import GridContext, GridWorld
from zsbfm.envs.pointmass import MazeContext, PointMass
from zsbfm.envs.registry import EnvSpec, env_names, env_spec, make_env, register

ENV_NAMES = env_names()


__all__ = ["AntWind", "WindContext", "Env", "EnvBase", "EnvSpec", "EnvState", "GridContext", "GridWorld",
           "MazeContext", "PointMass", "ENV_NAMES", "make_env", "env_spec", "env_names", "register",
           "index_contexts", "num_contexts"]
