"""One registry of environments: each env module registers its own facts here.

    register(EnvSpec(name="fourrooms", make=..., episode_len=100, discrete=True, ...))
    env = make_env("fourrooms", n_train=10)   # every caller builds envs through this
    spec = env_spec("fourrooms")               # the facts Config validates against

An EnvSpec holds what the rest of the framework needs to know about an environment without
building it: its episode length, action type, default / maximum number of train contexts,
and its preset overrides per size (Config.preset layers them under the algorithm's).
"""

from __future__ import annotations

import dataclasses
from typing import Any, Callable


@dataclasses.dataclass(frozen=True)
class EnvSpec:
    name: str
    make: Callable[..., Any]          # make(n_train: int, episode_len: int) -> Env
    episode_len: int                  # steps per episode (data, contexts)
    discrete: bool                    # discrete actions (argmax policy) or continuous (actor)
    n_train: int                      # default number of train contexts
    max_train: int | None = None      # at most this many train contexts (None: no limit)
    fixed_train: bool = False         # the train contexts are fixed: n_train must equal the default
    finite_states: bool = False       # env.states() enumerates every observation (Config.splus="exact")
    expert_behaviour: bool = False    # its data comes from a trained expert (zsbfm.data.expert; Config.data_policy)
    cell_map: bool = False            # positions fall in a map of cells: env.cell_index(obs), env.n_cells
    binary_context: bool = False      # env.context_features are 0/1 (a wall map): Config.context_loss="bce"
    revealed_context: bool = False    # env.revealed_features(obs, action, next_obs): Config.context_target="revealed"
    # env.pointed_cell(obs, action), env.cell_walls(ctx), env.cells_to_features(values): Config.enc_pool="evidence"
    pointed_cells: bool = False
    shares_data: bool = False         # one dataset, recorded once and cached, for every seed (zsbfm.data.sources)
    presets: dict = dataclasses.field(default_factory=dict)         # size -> Config overrides
    belief_presets: dict = dataclasses.field(default_factory=dict)  # size -> bfb / rfb overrides
    algo_presets: dict = dataclasses.field(default_factory=dict)    # size -> {algo: overrides}, applied last
    description: str = ""


_REGISTRY: dict[str, EnvSpec] = {}


def register(spec: EnvSpec) -> EnvSpec:
    """Add an environment (or replace one of the same name); returns the spec."""
    _REGISTRY[spec.name] = spec
    return spec


def env_names() -> tuple[str, ...]:
    return tuple(_REGISTRY)


def env_spec(name: str) -> EnvSpec:
    if name not in _REGISTRY:
        raise ValueError(f"unknown env {name!r}; available: {', '.join(_REGISTRY)}")
    return _REGISTRY[name]


def make_env(name: str, n_train: int | None = None, episode_len: int | None = None):
    """Build a registered environment: n_train train contexts (default: the env's own) and
    episodes of episode_len steps (default: the env's own)."""
    spec = env_spec(name)
    n = spec.n_train if n_train is None else n_train
    if spec.fixed_train and n != spec.n_train:
        raise ValueError(f"{name} has {spec.n_train} fixed train contexts, got n_train={n}")
    return spec.make(n_train=n, episode_len=spec.episode_len if episode_len is None else episode_len)
