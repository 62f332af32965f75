"""Where a run's data comes from: collected on device per seed, or one dataset shared by
every seed.

    shared = shared_dataset(cfg, env)   # a host Dataset, or None: collect per seed

- cfg.dataset = "path.npz": that file (written by `python -m zsbfm collect`, or a user's own
  with the arrays documented in zsbfm.data.dataset), checked against the env first;
- an env whose data is costly to record registers `EnvSpec(shares_data=True)` (AntWind: its noisy
  expert's episodes, recorded once and cached under cfg.data_dir by zsbfm.data.expert);
- otherwise None: every seed collects its own dataset on device from its data key
  (`zsbfm.data.collect`, the env's behaviour policy), inside the compiled program.

Both the pure `make_train(cfg).train(key)` and the host driver `zsbfm.train(cfg)` take the
data from here, so they train on the same data.
"""

from __future__ import annotations

import numpy as np

from zsbfm.data.dataset import Dataset, load_dataset
from zsbfm.envs.base import num_contexts
from zsbfm.envs.registry import env_spec, make_env


def make_env_for(cfg, progress: bool = True):
    """The environment of a Config, ready to collect data: `make_env` with the config's
    train contexts and episode length, with its trained behaviour expert attached when the
    env's data comes from one (EnvSpec.expert_behaviour: AntWind; trained once, cached)."""
    env = make_env(cfg.env, n_train=cfg.n_train_layouts, episode_len=cfg.episode_len)
    if env_spec(cfg.env).expert_behaviour:
        from zsbfm.data.expert import with_expert

        env = with_expert(env, cfg, progress)
    return env


def check_dataset(ds: Dataset, env, cfg, path: str = "dataset") -> Dataset:
    """Raise a one-line ValueError if `ds` cannot be `cfg`'s training data on `env`."""
    obs, action, ctx = np.asarray(ds.obs), np.asarray(ds.action), np.asarray(ds.context_id)
    if obs.ndim != 3 or obs.shape[-1] != env.obs_dim:
        raise ValueError(f"{path}: obs has shape {obs.shape}, expected [episodes, T+1, {env.obs_dim}]")
    if obs.shape[1] - 1 != cfg.episode_len:
        raise ValueError(f"{path}: episodes of {obs.shape[1] - 1} steps, expected episode_len={cfg.episode_len}")
    want = (obs.shape[0], obs.shape[1] - 1) + (() if env.discrete else (env.action_dim,))
    if action.shape != want:
        raise ValueError(f"{path}: action has shape {action.shape}, expected {want}")
    n_ctx = num_contexts(env.contexts("train"))
    if ctx.shape != (obs.shape[0],) or ctx.min() < 0 or ctx.max() >= n_ctx:
        raise ValueError(f"{path}: context_id must be int[{obs.shape[0]}] in 0..{n_ctx - 1} (the train contexts)")
    per = cfg.episodes_per_layout
    if obs.shape[0] != n_ctx * per or not (ctx == np.repeat(np.arange(n_ctx), per)).all():
        raise ValueError(f"{path}: {obs.shape[0]} episodes; expected {n_ctx} contexts x episodes_per_layout={per}, "
                         "context-major (episode e in context e // episodes_per_layout)")
    return ds


def shared_dataset(cfg, env, progress: bool = True) -> Dataset | None:
    """The dataset every seed of `cfg` trains on, or None when each seed collects its own."""
    if cfg.dataset:
        return check_dataset(load_dataset(cfg.dataset), env, cfg, cfg.dataset)
    if env_spec(cfg.env).shares_data:
        from zsbfm.data.expert import load_or_collect_dataset

        return load_or_collect_dataset(cfg, env, progress)
    return None
