"""Successor-feature baselines: HILP (Park et al. 2024) and Laplacian (Wu et al. 2019).

Both learn state features phi(s) in R^d with their own loss, and successor features
    psi(s, a, z) ~= E[ sum_t gamma^t c_{t+1} | s, a, pi_z ],   Q(s, a, z) = psi(s, a, z)^T z,
for a cumulant c built from phi (stop-gradient):
    HILP:       c = phi(s') - phi(s)    (intrinsic reward (phi(s') - phi(s))^T z)
    Laplacian:  c = phi(s')
psi is FB's twin forward network and is trained by the same update, target policy and
z sampler as FB (`FBAgent`): only the loss and the task inference differ. In `FBParams`,
F holds psi and B holds phi.

Losses (one optimiser step on the sum; phi gets gradients from its own loss only):
    SF:   sum_k 0.5 * mean_i |psi_k(s_i, a_i, z_i) - (c_i + gamma * psibar(s'_i, pi(s'_i), z_i))|^2
          (psibar: the mean of the twin target heads, as in FB)
    HILP: IQL expectile regression of V(s, g) = -|phi(s) - phi(g)| (twin phi heads), reward
          -1 until s = g, goals g = a future state of the same episode (prob p) or a random one
    LAP:  mean |phi(s) - phi(s')|^2 + ortho_coef * orthonormality of phi over the batch

Task inference: goal reaching, HILP z = sqrt(d) normalize(phi(g) - phi(s)) recomputed at
every step; Laplacian z = sqrt(d) normalize(phi(g)). Rewards: z = least squares of r on phi.
"""

from __future__ import annotations

import abc
import dataclasses
from typing import Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp
import optax

from zsbfm.agents.base import Context, Task
from zsbfm.agents.fb import FBAgent, FBParams, ortho_loss
from zsbfm.data.samplers import Transitions, sample_future, sample_states
from zsbfm.nets.mlp import MLP
from zsbfm.ops.sphere import project_to_sphere

Array = jax.Array


class FeatureNet(nn.Module):
    """phi(s) -> float32[heads, ..., d] (unnormalised); `heads` independent MLPs."""

    d: int
    hidden: Sequence[int]
    heads: int = 1

    @nn.compact
    def __call__(self, obs):
        heads = nn.vmap(MLP, variable_axes={"params": 0}, split_rngs={"params": True},
                        in_axes=None, out_axes=0, axis_size=self.heads)
        return heads(self.hidden, self.d, name="phi")(obs)


def expectile_loss(adv: Array, diff: Array, expectile: float) -> Array:
    """IQL's asymmetric L2: |expectile - 1(adv < 0)| * diff^2."""
    weight = jnp.where(adv >= 0, expectile, 1.0 - expectile)
    return weight * diff**2


def lstsq_z(phi: Array, reward: Array, ridge: float = 1e-4) -> Array:
    """argmin_z sum_i (r_i - phi_i^T z)^2 + ridge |z|^2 for phi [n, d], reward [n]."""
    d = phi.shape[-1]
    A = phi.T @ phi / phi.shape[0] + ridge * jnp.eye(d)
    return jnp.linalg.solve(A, phi.T @ reward / phi.shape[0])


@dataclasses.dataclass(frozen=True)
class SFAgent(FBAgent, abc.ABC):
    """Successor features on learned features phi; subclasses define phi's loss and c
    (abstract: SFAgent itself cannot be built)."""

    phi_heads = 1

    @property
    def B_net(self) -> FeatureNet:  # the state-embedding slot of FBParams holds phi
        return FeatureNet(self.cfg.d, self.cfg.feat_hidden, self.phi_heads)

    def phi(self, phi_params, obs: Array) -> Array:
        """The features the successor features are built on: [..., d] (head 0)."""
        return self.B_net.apply(phi_params, self.obs_features(obs))[0]

    def backward(self, B_params, obs: Array) -> Array:
        """The embedding FB's z sampler mixes in: phi(s) on the sqrt(d)-sphere."""
        return project_to_sphere(self.phi(B_params, obs))

    def update_target(self, params: FBParams, target: FBParams) -> FBParams:
        """psi (and the actor) at rate tau, phi at its own rate feat_tau."""
        new = super().update_target(params, target)
        return new.replace(B=optax.incremental_update(params.B, target.B, self.cfg.feat_tau))

    # -- the losses --------------------------------------------------------------------------
    @abc.abstractmethod
    def cumulant(self, phi_params, batch: Transitions) -> Array:
        """c(s, s') [n, d] from phi (HILP: phi(s') - phi(s); Laplacian: phi(s'))."""

    @abc.abstractmethod
    def feature_loss(self, params: FBParams, target: FBParams, batch: Transitions, aux) -> tuple[Array, dict]:
        """phi's own loss and its metrics."""

    def loss(self, params: FBParams, target: FBParams, batch: Transitions, task: Task, aux: dict):
        """SF TD loss (psi) + the feature loss (phi)."""
        psi = self.forward_sa(params.F, batch.obs, batch.action, task)        # [2, n, d]
        c = self.cumulant(jax.lax.stop_gradient(params.B), batch)            # [n, d]
        next_psi = jnp.mean(self.target_next_F(target, batch.next_obs, task, aux), 0)
        y = jax.lax.stop_gradient(c + self.cfg.gamma * next_psi)
        l_sf = jnp.sum(0.5 * jnp.mean(jnp.sum((psi - y[None]) ** 2, -1), -1))
        l_phi, metrics = self.feature_loss(params, target, batch, aux)
        l_actor, m_actor = self.actor_loss(params, batch, task)
        metrics = dict(metrics, **m_actor, sf_loss=l_sf, phi_loss=l_phi,
                       q_mean=jnp.mean(jnp.einsum("knd,nd->kn", psi, task.z)))
        return l_sf + l_phi + l_actor, metrics

    # -- test time ---------------------------------------------------------------------------
    def reward_task(self, params: FBParams, obs: Array, reward: Array, context: Context) -> Task:
        """z = sqrt(d) normalize(least squares of r on phi(s)).

        For HILP's cumulant phi(s') - phi(s) this is still the right z: sum_t gamma^t
        (phi_{t+1} - phi_t)^T z is a potential-based shaping of the reward phi(s')^T z
        (same optimal policy, exactly so without truncation)."""
        z = project_to_sphere(lstsq_z(self.phi(params.B, obs), reward))
        return Task(z=z, h=self.context_h(params, context))


@dataclasses.dataclass(frozen=True)
class HILPAgent(SFAgent):
    """HILP: phi is a temporal-distance embedding, -|phi(s) - phi(g)| = V(s, g)."""

    phi_heads = 2  # twin value heads; phi = head 0

    def value(self, phi_all_s: Array, phi_all_g: Array) -> Array:
        """V_k(s, g) = -|phi_k(s) - phi_k(g)|: [heads, n] (eps inside the sqrt: finite gradient at 0)."""
        return -jnp.sqrt(jnp.sum((phi_all_s - phi_all_g) ** 2, -1) + 1e-6)

    def aux_batch(self, dataset, batch: Transitions, key: Array, stats: dict | None = None) -> dict:
        """Adds "goals": with prob hilp_p_traj_goal a future state s_{t+k} of the same
        episode, k ~ Geometric(1 - feat_gamma); otherwise a uniformly random dataset state."""
        k_base, k_fut, k_rand, k_mix = jax.random.split(key, 4)
        future = sample_future(k_fut, dataset, batch.episode, batch.t, self.cfg.feat_gamma)
        rand = sample_states(k_rand, dataset, batch.obs.shape[0])
        use_future = jax.random.uniform(k_mix, batch.obs.shape[:1]) < self.cfg.hilp_p_traj_goal
        return dict(super().aux_batch(dataset, batch, k_base, stats), goals=jnp.where(use_future[:, None], future, rand))

    def feature_loss(self, params, target, batch, aux):
        c = self.cfg
        goals = aux["goals"]
        phi = lambda p, x: self.B_net.apply(p, self.obs_features(x))        # [2, n, d]
        g_online, g_target = phi(params.B, goals), phi(target.B, goals)
        v = self.value(phi(params.B, batch.obs), g_online)                    # [2, n]
        v_t = self.value(phi(target.B, batch.obs), g_target)
        next_v_t = self.value(phi(target.B, batch.next_obs), g_target)
        # s = g exactly (HILP's index equality): with continuous states this almost never
        # fires, and V(g, g) = 0 holds by construction of -|phi(s) - phi(g)|.
        reached = jnp.all(batch.obs == goals, -1)
        reward, mask = reached.astype(jnp.float32) - 1.0, 1.0 - reached.astype(jnp.float32)
        # IQL: the advantage uses the min over target heads for s' and their mean for s.
        q = reward + c.feat_gamma * mask * jnp.min(next_v_t, 0)
        adv = q - jnp.mean(v_t, 0)
        q_k = jax.lax.stop_gradient(reward + c.feat_gamma * mask * next_v_t)   # [2, n]
        loss = jnp.sum(jnp.mean(expectile_loss(jax.lax.stop_gradient(adv), q_k - v, c.hilp_expectile), -1))
        return loss, {"hilp_v": jnp.mean(v), "hilp_adv": jnp.mean(adv)}

    def cumulant(self, phi_params, batch):
        return self.phi(phi_params, batch.next_obs) - self.phi(phi_params, batch.obs)

    def goal_z(self, params, obs, goal_obs):
        """HILP's goal direction sqrt(d) normalize(phi(g) - phi(s)): FB's z sampler mixes it in."""
        return project_to_sphere(self.phi(params.B, goal_obs) - self.phi(params.B, obs))

    def goal_task(self, params, goal_obs, context):
        """The goal is kept embedded; `act` turns it into z = normalize(phi(g) - phi(s))."""
        g = self.phi(params.B, goal_obs)
        return Task(z=project_to_sphere(g), h=self.context_h(params, context), goal=g)

    def state_task(self, params, obs, task: Task) -> Task:
        """For a goal task, z = sqrt(d) normalize(phi(g) - phi(s)) at the current state."""
        if task.goal is None:
            return task
        return task.replace(z=project_to_sphere(task.goal - self.phi(params.B, obs)))

    def q_values(self, params, obs, task: Task):
        return super().q_values(params, obs, self.state_task(params, obs, task))

    def act(self, params, obs, task: Task, key):
        return super().act(params, obs, self.state_task(params, obs, task), key)


@dataclasses.dataclass(frozen=True)
class LaplacianAgent(SFAgent):
    """Laplacian eigenfunctions: phi smooth along transitions, orthonormal under the data."""

    def feature_loss(self, params, target, batch, aux):
        phi_s, phi_next = self.phi(params.B, batch.obs), self.phi(params.B, batch.next_obs)
        smooth = jnp.mean(jnp.sum((phi_s - phi_next) ** 2, -1))
        ortho = ortho_loss(phi_s)
        return smooth + self.cfg.ortho_coef * ortho, {"lap_smooth": smooth, "lap_ortho": ortho}

    def cumulant(self, phi_params, batch):
        return self.phi(phi_params, batch.next_obs)
