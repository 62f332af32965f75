"""Forward and backward networks of FB (and of its Belief/Rotation flavours).

F(s, a, w) with w the task input (z for FB, [z; h] for the belief flavours):
two preprocessors embed (s) or (s, a) and (s, w) separately, their outputs are
concatenated and an MLP maps them to d (continuous actions) or |A| x d (discrete).
B(s) is an MLP to d, projected onto the sphere of radius sqrt(d).
"""

from __future__ import annotations

from typing import Sequence

import flax.linen as nn
import jax.numpy as jnp

from zsbfm.nets.mlp import MLP
from zsbfm.ops.sphere import project_to_sphere


class ForwardNet(nn.Module):
    """F(s, [a,] w) -> float32[..., d] (continuous) or float32[..., n_actions, d] (discrete)."""

    d: int
    n_actions: int  # 0 for continuous actions
    pre_hidden: Sequence[int]
    pre_out: int
    hidden: Sequence[int]

    h_in_sa: int = 0  # > 0: the last h_in_sa entries of `task` (the context h) also enter pre_sa

    @nn.compact
    def __call__(self, obs, task, action=None):
        sa = obs if action is None else jnp.concatenate([obs, action], -1)
        if self.h_in_sa:
            sa = jnp.concatenate([sa, task[..., task.shape[-1] - self.h_in_sa:]], -1)
        e_sa = MLP(self.pre_hidden, self.pre_out, name="pre_sa")(sa)
        e_sw = MLP(self.pre_hidden, self.pre_out, name="pre_sw")(jnp.concatenate([obs, task], -1))
        x = jnp.concatenate([e_sa, e_sw], -1)
        if self.n_actions:
            out = MLP(self.hidden, self.d * self.n_actions, name="trunk")(x)
            return out.reshape(*out.shape[:-1], self.n_actions, self.d)
        return MLP(self.hidden, self.d, name="trunk")(x)


class TwinForward(nn.Module):
    """Two independent ForwardNets evaluated together: output has a leading axis of 2."""

    d: int
    n_actions: int
    pre_hidden: Sequence[int]
    pre_out: int
    hidden: Sequence[int]
    h_in_sa: int = 0

    @nn.compact
    def __call__(self, obs, task, action=None):
        twin = nn.vmap(ForwardNet, variable_axes={"params": 0}, split_rngs={"params": True},
                       in_axes=None, out_axes=0, axis_size=2)
        return twin(self.d, self.n_actions, self.pre_hidden, self.pre_out, self.hidden,
                    self.h_in_sa, name="F")(obs, task, action)


class BackwardNet(nn.Module):
    """B(s) -> float32[..., d] with |B(s)| = sqrt(d)."""

    d: int
    hidden: Sequence[int]

    @nn.compact
    def __call__(self, obs):
        return project_to_sphere(MLP(self.hidden, self.d)(obs))


class Actor(nn.Module):
    """Deterministic policy pi(s, w) -> tanh(MLP([s; w])) in [-1, 1]^action_dim."""

    action_dim: int
    hidden: Sequence[int]

    @nn.compact
    def __call__(self, obs, task):
        return jnp.tanh(MLP(self.hidden, self.action_dim)(jnp.concatenate([obs, task], -1)))
