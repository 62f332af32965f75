"""The offline dataset: episode-major arrays that keep episode boundaries.

Layout (E episodes of T steps; `obs` holds the T+1 states of each episode):

    obs:        float32[E, T+1, obs_dim]  s_0 .. s_T
    action:     int32[E, T] (discrete) or float32[E, T, action_dim] (continuous), a_t
    context_id: int32[E]                  index of the episode's layout in its context set

The transition t of episode e is (obs[e, t], action[e, t], obs[e, t+1]); nothing ever
crosses from one episode into the next. On disk a dataset is one `.npz` file with exactly
these three arrays (`np.load(path)` reads it without zsbfm).
"""

from __future__ import annotations

import os

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct


@struct.dataclass
class Dataset:
    obs: jax.Array
    action: jax.Array
    context_id: jax.Array

    @property
    def num_episodes(self) -> int:
        return self.obs.shape[-3]

    @property
    def episode_len(self) -> int:
        return self.obs.shape[-2] - 1  # obs holds s_0 .. s_T

    @property
    def num_transitions(self) -> int:
        return self.num_episodes * self.episode_len


def save_dataset(path: str, ds: Dataset) -> str:
    """Write `ds` to `path` as an uncompressed .npz with keys obs, action, context_id."""
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    np.savez(path, obs=np.asarray(ds.obs), action=np.asarray(ds.action),
             context_id=np.asarray(ds.context_id))
    return path


def load_dataset(path: str) -> Dataset:
    """Read a dataset written by `save_dataset` (or any .npz with the same three arrays)."""
    with np.load(path) as f:
        missing = {"obs", "action", "context_id"} - set(f.files)
        if missing:
            raise ValueError(f"{path}: not a zsbfm dataset, missing arrays {sorted(missing)}")
        return Dataset(obs=jnp.asarray(f["obs"]), action=jnp.asarray(f["action"]),
                       context_id=jnp.asarray(f["context_id"]))
