"""Forward and backward networks of FB (and of its Belief/Rotation flavours).

F(s, a, w) with w the task input (z for FB, [z; h] for the belief flavours):
two preprocessors embed (s) or (s, a) and (s, w) separately, their outputs are
concatenated and an MLP maps them to d (continuous actions) or |A| x d (discrete).
Config.f_arch:
  "reference": the two-preprocessor layout of Meta's FB code (controllable_agent's and
               metamotivo's continuous-control ForwardMap): preprocessor = Linear ->
               LayerNorm -> tanh, then Linear -> ReLU to pre_out; trunk = Linear -> ReLU
               layers, then a linear output.
  "normed_trunk": this project's F before f_arch existed: linear preprocessor outputs and a
               trunk whose first layer is Linear -> LayerNorm -> tanh again (saved runs
               without the field load with it). On one Four-Rooms layout it made the
               worse F (README, Presets).
  "mlp":       the authors' layout (BeliefConditionedFB; also controllable_agent's discrete
               ForwardMap, `preprocess=False`): one trunk on [s, a, z, h] (`NormedMLP`:
               tanh + LayerNorm after the first layer, GELU + LayerNorm after the others,
               orthogonal init); the preprocessor fields are unused. B uses it too.
B(s) is an MLP to d, projected onto the sphere of radius sqrt(d).

The context h (the last h_dim entries of w) is an input of F: beside z in pre_sw (the
paper's wiring), and in pre_sa too when Config.h_in_sa. (FiLM and outer-product
conditioning were tried and removed: docs/experiments.md, "Removed options".)
"""

from __future__ import annotations

import dataclasses
from typing import Sequence

import flax.linen as nn
import jax.numpy as jnp

from zsbfm.names import F_ARCHS
from zsbfm.nets.mlp import MLP, NormedMLP
from zsbfm.ops.sphere import project_to_sphere


class ForwardNet(nn.Module):
    """F(s, [a,] w) -> float32[..., d] (continuous) or float32[..., n_actions, d] (discrete).

    obs: [..., obs_feat]; task w = [z; h]: [..., d + h_dim]; action: [..., action_dim] or None.
    h_dim: the number of trailing entries of w that are the context h (0: no context).
    h_in_sa: h also enters pre_sa.
    """

    d: int
    n_actions: int  # 0 for continuous actions
    pre_hidden: Sequence[int]
    pre_out: int
    hidden: Sequence[int]
    h_dim: int = 0
    h_in_sa: bool = False
    arch: str = "reference"

    @nn.compact
    def __call__(self, obs, task, action=None):
        if self.arch not in F_ARCHS:
            raise ValueError(f"arch={self.arch!r} is invalid: expected one of {F_ARCHS}")
        out = self.d * self.n_actions if self.n_actions else self.d
        sa = obs if action is None else jnp.concatenate([obs, action], -1)
        if self.arch == "mlp":  # one trunk on [s, a, w] (h is already in w; h_in_sa unused)
            y = NormedMLP(self.hidden, out, name="trunk")(jnp.concatenate([sa, task], -1))
            return y.reshape(*y.shape[:-1], self.n_actions, self.d) if self.n_actions else y
        if self.h_in_sa and self.h_dim:
            sa = jnp.concatenate([sa, task[..., task.shape[-1] - self.h_dim:]], -1)
        sw = jnp.concatenate([obs, task], -1)
        ref = self.arch == "reference"
        pre, trunk = dict(out_relu=ref), dict(norm_first=not ref)
        e_sa = MLP(self.pre_hidden, self.pre_out, name="pre_sa", **pre)(sa)
        e_sw = MLP(self.pre_hidden, self.pre_out, name="pre_sw", **pre)(sw)
        y = MLP(self.hidden, out, name="trunk", **trunk)(jnp.concatenate([e_sa, e_sw], -1))
        if self.n_actions:
            return y.reshape(*y.shape[:-1], self.n_actions, self.d)
        return y


class TwinForward(ForwardNet):
    """`heads` independent ForwardNets (same fields; 2 = the twin F) evaluated together as
    one batched network: output has a leading axis of `heads`; parameters under "F" with a
    leading axis of `heads`."""

    heads: int = 2

    @nn.compact
    def __call__(self, obs, task, action=None):
        twin = nn.vmap(ForwardNet, variable_axes={"params": 0}, split_rngs={"params": True},
                       in_axes=None, out_axes=0, axis_size=self.heads)
        fields = {f.name: getattr(self, f.name) for f in dataclasses.fields(ForwardNet)
                  if f.name not in ("parent", "name")}
        return twin(**fields, name="F")(obs, task, action)


class BackwardNet(nn.Module):
    """B(s) -> float32[..., d] with |B(s)| = sqrt(d). arch "mlp": the authors' NormedMLP;
    any other: `MLP` (Linear -> LayerNorm -> tanh, then ReLU layers)."""

    d: int
    hidden: Sequence[int]
    arch: str = "reference"

    @nn.compact
    def __call__(self, obs):
        net = NormedMLP(self.hidden, self.d) if self.arch == "mlp" else MLP(self.hidden, self.d)
        return project_to_sphere(net(obs))


class Actor(nn.Module):
    """Deterministic policy pi(s, w) -> tanh(MLP([s; w])) in [-1, 1]^action_dim."""

    action_dim: int
    hidden: Sequence[int]

    @nn.compact
    def __call__(self, obs, task):
        return jnp.tanh(MLP(self.hidden, self.action_dim)(jnp.concatenate([obs, task], -1)))
