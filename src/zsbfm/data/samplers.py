"""Jittable samplers over an episode-major `Dataset`.

All samplers draw indices uniformly (episode e ~ U{0..E-1}, step t ~ U{0..T-1}) and
gather; they never cross an episode boundary.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from zsbfm.data.dataset import Dataset


@struct.dataclass
class Transitions:
    """A batch of transitions (s_t, a_t, s_{t+1}) with where they came from."""

    obs: jax.Array        # [n, obs_dim]
    action: jax.Array     # [n] or [n, action_dim]
    next_obs: jax.Array   # [n, obs_dim]
    episode: jax.Array    # int32[n]
    t: jax.Array          # int32[n]


def sample_transitions(key: jax.Array, ds: Dataset, n: int) -> Transitions:
    """n transitions drawn uniformly from the whole dataset."""
    k_e, k_t = jax.random.split(key)
    ep = jax.random.randint(k_e, (n,), 0, ds.num_episodes)
    t = jax.random.randint(k_t, (n,), 0, ds.episode_len)
    return shard_batch(Transitions(obs=ds.obs[ep, t], action=ds.action[ep, t], next_obs=ds.obs[ep, t + 1],
                                   episode=ep, t=t))


DATA_AXIS = "data"  # the mesh axis a data-parallel batch is split over (Config.data_parallel)


def shard_batch(batch):
    """The data-parallel hook: split the batch (leading axis of every leaf) over the "data"
    axis of the mesh the program is traced under (zsbfm.train.on_mesh); a no-op without
    one or when it has size 1 (Config.data_parallel = 1: the program is unchanged).

    Only a sharding constraint: the maths is the global batch's. GSPMD partitions
    everything downstream (gathers, forward passes, the n x n FB matrix, whose B operand
    it all-gathers) and turns the batch reductions of the loss -- and so of its gradient
    with respect to the parameters, which are replicated over "data" -- into all-reduces.
    Each device does 1/data_parallel of the per-transition work and the update equals
    the single-device one on the same batch up to float summation order. (Averaging
    per-device losses instead, as pmap-style data parallelism does, would change the FB
    and orthonormality estimators: their off-diagonal terms would only pair transitions
    that landed on the same device.) The random draws do not depend on the sharding
    (jax_threefry_partitionable, the default)."""
    size = jax.sharding.get_abstract_mesh().shape.get(DATA_AXIS, 1)
    if size == 1:
        return batch
    spec = jax.sharding.PartitionSpec(DATA_AXIS)
    return jax.tree_util.tree_map(lambda x: jax.lax.with_sharding_constraint(x, spec), batch)


def sample_states(key: jax.Array, ds: Dataset, n: int) -> jax.Array:
    """n states drawn uniformly from all stored states s_1..s_T (float32[n, obs_dim])."""
    k_e, k_t = jax.random.split(key)
    ep = jax.random.randint(k_e, (n,), 0, ds.num_episodes)
    t = jax.random.randint(k_t, (n,), 1, ds.episode_len + 1)
    return shard_batch(ds.obs[ep, t])  # one per batch row (training z, goals): split like the batch


def geometric_offsets(key: jax.Array, shape, gamma: float) -> jax.Array:
    """k >= 1 with P(k) = (1 - gamma) gamma^(k-1) (int32)."""
    u = jax.random.uniform(key, shape, minval=jnp.finfo(jnp.float32).tiny, maxval=1.0)
    return (jnp.floor(jnp.log(u) / jnp.log(gamma)) + 1).astype(jnp.int32)


def sample_future(key: jax.Array, ds: Dataset, episode: jax.Array, t: jax.Array,
                  gamma: float) -> jax.Array:
    """Future states s_{t+k} of the same episode, k ~ Geometric(1 - gamma), k >= 1.

    Offsets running past the episode's last state are truncated to s_T (the episode's
    end), so the law is geometric up to the boundary. float32[n, obs_dim].
    """
    k = geometric_offsets(key, episode.shape, gamma)
    return ds.obs[episode, jnp.minimum(t + k, ds.episode_len)]


def sample_windows(key: jax.Array, ds: Dataset, episode: jax.Array, length: int):
    """A contiguous window of `length` transitions from each given episode.

    The window start is uniform in 0..T-length. Returns (obs [n, L, obs_dim],
    action [n, L, ...], next_obs [n, L, obs_dim]).
    """
    if length > ds.episode_len:
        raise ValueError(f"window length {length} is longer than an episode ({ds.episode_len})")
    start = jax.random.randint(key, episode.shape, 0, ds.episode_len - length + 1)
    idx = start[:, None] + jnp.arange(length)[None, :]
    ep = episode[:, None]
    return ds.obs[ep, idx], ds.action[ep, idx], ds.obs[ep, idx + 1]
