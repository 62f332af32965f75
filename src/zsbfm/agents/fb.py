"""Forward-Backward representations (Touati & Ollivier 2021), discrete or continuous actions.

The successor measure of the policy pi_z is modelled as
    M^{pi_z}(s, a, ds+) ~= F(s, a, w)^T B(s+) rho(ds+),     w = [z; h],
with Q(s, a) = min_k F_k(s, a, w)^T z. The two action spaces share the loss and the z
sampling; only the policy and the target action differ:
    discrete:    F(s, w) -> [A, d]; pi = argmax_a Q (target: greedy/Boltzmann/uniform);
    continuous:  F(s, a, w) -> d; a deterministic tanh actor pi(s, w) trained TD3-style to
                 maximise min_k F_k(s, pi(s, w), w)^T z (F frozen in that loss); target
                 action pi_target(s', w) + clip(N(0, 0.2^2), -0.3, 0.3), clipped to [-1, 1].

`FBAgent` is written as a small set of hooks so the Belief- and Rotation-FB flavours reuse
everything here and override only what differs:
    train_context(...)  -> h for a batch   (FB: empty, h_dim = 0)
    train_z(...)        -> z for a batch   (FB: uniform sphere mixed with B(s))
    context_task_h(...) -> h at test time  (FB: empty)
The TD loss (`fb_loss`), the orthonormality loss and the z sampler are plain functions
shared by every flavour and by the continuous-action variant.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import optax
from flax import struct

from zsbfm.agents.base import Context, Task
from zsbfm.config import Config
from zsbfm.data.samplers import Transitions, sample_states, sample_transitions
from zsbfm.envs.base import Env
from zsbfm.nets.fb import Actor, BackwardNet, TwinForward
from zsbfm.ops.sphere import project_to_sphere, sample_sphere

Array = jax.Array


# --- Shared maths ------------------------------------------------------------------------

def heads_times(F: Array, B: Array) -> Array:
    """M_k = F_k B^T for every head: F [K, n, d], B [m, d] -> [K, n, m], as one [K n, d] x
    [d, m] product. The same sums as einsum("knd,md->knm"), but B's gradient then contracts
    the one flat K n axis, which XLA's CPU dot reads in place, where the einsum's (K, n) pair
    had it first copy the [K, n, m] gradient into a transposed layout."""
    K, n, d = F.shape
    return (F.reshape(K * n, d) @ B.T).reshape(K, n, B.shape[0])


def fb_loss(F: Array, B: Array, target_M: Array, gamma: float) -> tuple[Array, dict]:
    """The FB temporal-difference loss, summed over the twin heads.

    F:        [K, n, d]  F_k(s_i, a_i, w_i) for the batch's (s, a, w)
    B:        [n, d]     B(s'_j) for the batch's next states
    target_M: [n, n]     Fbar(s'_i, pi(s'_i), w_i)^T Bbar(s'_j), mean or min over the
                         twin heads                                           (stop-gradient)

    L = sum_k [ 0.5 * mean_{i != j} (M_k[i, j] - gamma target_M[i, j])^2 - mean_i M_k[i, i] ]
    with M_k = F_k B^T: the off-diagonal pairs estimate the measure on independent
    s+ ~ rho, the diagonal rewards the observed transition s -> s'.
    """
    n = B.shape[0]
    target_M = jax.lax.stop_gradient(target_M)
    M = heads_times(F, B)
    off = 1.0 - jnp.eye(n)
    offdiag = 0.5 * jnp.sum((M - gamma * target_M) ** 2 * off, axis=(1, 2)) / (n * (n - 1))
    diag = -jnp.mean(jnp.diagonal(M, axis1=1, axis2=2), axis=1)
    loss = jnp.sum(offdiag + diag)
    return loss, {"fb_offdiag": jnp.sum(offdiag), "fb_diag": jnp.sum(diag),
                  "M_diag": jnp.mean(jnp.diagonal(M, axis1=1, axis2=2)),
                  "M_offdiag": jnp.sum(M * off) / (M.shape[0] * n * (n - 1))}


def fb_loss_splus(F: Array, B_next: Array, B_plus: Array, target_M: Array, gamma,
                  rho: Array | None = None) -> tuple[Array, dict]:
    """The same TD loss with the s+ side taken from states independent of the batch.

    F:        [K, n, d]  F_k(s_i, a_i, w_i)
    B_next:   [n, d]     B(s'_i) (the diagonal term: the observed transitions)
    B_plus:   [m, d]     B(s+_j) for states s+_j ~ rho (Config.splus)
    target_M: [n, m]     Fbar(s'_i, pi(s'_i), w_i)^T Bbar(s+_j)                 (stop-gradient)
    rho:      [m] or None: weights of the s+ rows (an exact expectation over a finite state
              set, summing to 1); None: the rows are samples, weighted 1/m each.

    L = sum_k [ 0.5 * E_{s+ ~ rho} mean_i (F_k(s_i,a_i)^T B(s+) - gamma target_M[i, s+])^2
                - mean_i F_k(s_i, a_i)^T B(s'_i) ]
    Every (i, j) pair is independent here, so no diagonal is excluded.
    """
    target_M = jax.lax.stop_gradient(target_M)
    M = heads_times(F, B_plus)
    w = jnp.full(B_plus.shape[:1], 1.0 / B_plus.shape[0]) if rho is None else rho
    offdiag = 0.5 * jnp.einsum("knm,m->k", (M - gamma * target_M) ** 2, w) / F.shape[1]
    M_diag = jnp.einsum("knd,nd->kn", F, B_next)
    diag = -jnp.mean(M_diag, axis=1)
    return jnp.sum(offdiag + diag), {"fb_offdiag": jnp.sum(offdiag), "fb_diag": jnp.sum(diag),
                                     "M_diag": jnp.mean(M_diag),
                                     "M_offdiag": jnp.mean(jnp.einsum("knm,m->kn", M, w))}


def head_gap(Ms: Array, rho: Array | None = None, exclude_diag: bool = False) -> Array:
    """The twin heads' disagreement on the s+ side of the loss: E_{i, s+} [max_k Ms_k - min_k Ms_k]
    (= E |M_1 - M_2| for two heads). Ms: [K, n, m]; rho [m] weights the s+ columns (None:
    uniform); exclude_diag: the batch estimator's pairs i != j (m = n).

    With a min target the off-diagonal mean of M has the fixed point
    (1 - gamma gap / 2) / (1 - gamma): stable only while the heads agree (docs/results.md)."""
    spread = jnp.max(Ms, 0) - jnp.min(Ms, 0)                                  # [n, m]
    if exclude_diag:
        n = spread.shape[0]
        return jnp.sum(spread * (1.0 - jnp.eye(n))) / (n * (n - 1))
    w = jnp.full(spread.shape[1:], 1.0 / spread.shape[1]) if rho is None else rho
    return jnp.mean(spread @ w)


def ortho_loss(B: Array) -> Array:
    """Orthonormality of B over a batch: -2 mean diag(B B^T) + mean offdiag(B B^T)^2."""
    n = B.shape[0]
    cov = B @ B.T
    off = 1.0 - jnp.eye(n)
    return -2.0 * jnp.mean(jnp.diagonal(cov)) + jnp.sum((cov * off) ** 2) / (n * (n - 1))


def ortho_loss_weighted(B: Array, rho: Array) -> Array:
    """The exact expectation of the orthonormality loss over states s, s' ~ rho independent:
    E (B(s)^T B(s'))^2 - 2 E |B(s)|^2 = |C|_F^2 - 2 tr C, with C = sum_j rho_j B_j B_j^T [d, d].
    B: [m, d] every state of a finite set; rho: [m] its weights (summing to 1)."""
    C = jnp.einsum("m,md,me->de", rho, B, B)
    return jnp.sum(C**2) - 2.0 * jnp.trace(C)


def q_loss(F: Array, target_F: Array, B_next: Array, B_plus: Array, z: Array, gamma,
           rho: Array | None = None) -> Array:
    """The TD loss of the scalar Q = F^T z itself (controllable_agent's optional "q_loss"),
    summed over the heads:

        sum_k mean_i (F_k(s_i, a_i, w_i)^T z_i - [r_i + gamma * min_k' Fbar_k'(s'_i, pi, w_i)^T z_i])^2

    with the implicit reward of z_i, r_i = B(s'_i)^T C^-1 z_i, C = E_rho[B B^T] [d, d] (the
    reward whose Q is F^T z when M = F^T B rho): from the s+ states B_plus [m, d], weighted
    by rho [m] or uniformly. The target (reward and next Q) is stop-gradient. It weighs the
    one direction of F the policy reads (z) above the rest of the measure.
    F, target_F: [K, n, d]; B_next: [n, d]; z: [n, d]."""
    w = jnp.full(B_plus.shape[:1], 1.0 / B_plus.shape[0]) if rho is None else rho
    C = jnp.einsum("m,md,me->de", w, B_plus, B_plus)
    C = C + 1e-4 * jnp.trace(C) / C.shape[0] * jnp.eye(C.shape[0])  # never singular (m < d)
    reward = jnp.einsum("nd,nd->n", B_next, jnp.linalg.solve(C, z.T).T)
    next_q = jnp.min(jnp.einsum("knd,nd->kn", target_F, z), 0)
    target = jax.lax.stop_gradient(reward + gamma * next_q)
    q = jnp.einsum("knd,nd->kn", F, z)
    return jnp.sum(jnp.mean((q - target[None]) ** 2, axis=1))


def clip_by_global_norm(grads, max_norm) -> Any:
    """grads scaled by min(1, max_norm / |grads|) (global L2 norm); max_norm = 0: unchanged.
    Written with jnp.where rather than a Python branch so max_norm can be a traced value
    (a vmapped sweep over Config.clip_norm)."""
    norm = optax.tree.norm(grads)
    scale = jnp.where(max_norm > 0, jnp.minimum(1.0, max_norm / (norm + 1e-12)), 1.0)
    return jax.tree_util.tree_map(lambda g: g * scale, grads)


def mix_z(key: Array, z_prior: Array, z_states: Array, mix: float) -> Array:
    """Per row: z_states with probability `mix`, else z_prior (one key, used once)."""
    use_states = jax.random.uniform(key, z_prior.shape[:1]) < mix
    return jnp.where(use_states[:, None], z_states, z_prior)


def target_policy_weights(q: Array, policy: str, temperature: float) -> Array:
    """Target-policy probabilities [n, A] from next-state Q values q [n, A]."""
    if policy == "greedy":
        return jax.nn.one_hot(jnp.argmax(q, -1), q.shape[-1])
    if policy == "boltzmann":
        return jax.nn.softmax(q / temperature, -1)
    if policy == "uniform":  # a fixed policy: the measure of the uniform random walk
        return jnp.full(q.shape, 1.0 / q.shape[-1])
    raise ValueError(f"unknown target policy {policy!r}")


# --- State ---------------------------------------------------------------------------------

@struct.dataclass
class FBParams:
    F: Any             # forward network (successor features psi for the SF agents)
    B: Any             # backward network (features phi for the SF agents)
    enc: Any = None    # context encoder + predictor (belief flavours); None for FB
    actor: Any = None  # deterministic policy (continuous actions); None for discrete


@struct.dataclass
class ParamAverage:
    """The parameters evaluation reads when Config.eval_ema = r > 0. After the n-th FB
    update (n = 1, 2, ...), avg <- avg + max(r, 1/n) * (params - avg): the plain mean of
    the first 1/r updates' parameters, then an exponential average over about 1/r updates.
    Training never reads it (the targets are `FBState.target`, at rate tau). enc is None:
    evaluation reads the online encoder (`FBAgent.eval_params`), so it is not averaged."""
    params: FBParams
    n: Array           # FB updates averaged so far (int32[])


def average_update(avg: ParamAverage, params: FBParams, rate: float) -> ParamAverage:
    """One step of `ParamAverage`'s recursion."""
    n = avg.n + 1
    step = jnp.maximum(rate, 1.0 / n.astype(jnp.float32))
    return ParamAverage(params=optax.incremental_update(params, avg.params, step), n=n)


@struct.dataclass
class FBState:
    params: FBParams
    target: FBParams
    opt_state: Any
    step: Array
    average: ParamAverage | None = None  # Config.eval_ema > 0 only


# --- Agent -----------------------------------------------------------------------------------

@dataclasses.dataclass(frozen=True)
class FBAgent:
    """Vanilla FB with discrete actions. Static settings only; state lives in FBState."""

    cfg: Config
    env: Env

    h_dim = 0  # dimension of the dynamics context h (0: context-free)

    # -- networks ----------------------------------------------------------------------
    @property
    def F_net(self) -> TwinForward:
        c = self.cfg
        return TwinForward(c.d, self.env.n_actions, c.f_pre_hidden, c.f_pre_out, c.f_hidden,
                           h_dim=self.h_dim, h_in_sa=c.h_in_sa, arch=c.f_arch,
                           heads=c.f_heads)

    @property
    def actor_net(self) -> Actor:
        return Actor(self.env.action_dim, self.cfg.actor_hidden)

    @property
    def B_net(self) -> BackwardNet:
        return BackwardNet(self.cfg.d, self.cfg.b_hidden, arch=self.cfg.f_arch)

    @property
    def optimizer(self) -> optax.GradientTransformation:
        """Adam at a constant lr."""
        return optax.adam(self.cfg.lr)

    def normalize_obs(self, obs: Array) -> Array:
        """Map observations from [obs_low, obs_high] to [0, 1].

        Not [-1, 1]: there the grid's centre cell maps to the zero vector, whose first
        layer output is the bias alone, so at initialisation B(centre) = 0 exactly.
        """
        low = jnp.asarray(self.env.obs_low, jnp.float32)
        high = jnp.asarray(self.env.obs_high, jnp.float32)
        return (obs - low) / (high - low)

    def obs_features(self, obs: Array) -> Array:
        """Network input for an observation (Config.obs_encoding).

        "raw":      the normalised coordinates, [..., obs_dim].
        "unscaled": the observation as the env emits it (gridworlds: integer cells 0..10,
                    the authors' input), [..., obs_dim].
        "onehot":   one-hot of each integer coordinate, [..., sum of (high - low + 1)]; for
                    grid observations. Same information as (x, y), but lets an MLP carve
                    the sharp wall discontinuities of a successor measure on a grid.
        """
        if self.cfg.obs_encoding == "raw":
            return self.normalize_obs(obs)
        if self.cfg.obs_encoding == "unscaled":
            return obs
        idx = jnp.round(obs - jnp.asarray(self.env.obs_low)).astype(jnp.int32)
        sizes = [int(h - l) + 1 for l, h in zip(self.env.obs_low, self.env.obs_high)]
        return jnp.concatenate([jax.nn.one_hot(idx[..., i], n) for i, n in enumerate(sizes)], -1)

    def forward(self, F_params, obs: Array, task: Task, action: Array | None = None) -> Array:
        """Discrete: F for all actions [2, ..., n_actions, d]; continuous: F(s, a, w) [2, ..., d]."""
        w = jnp.concatenate([task.z, task.h], -1)
        return self.F_net.apply(F_params, self.obs_features(obs), w, action)

    def forward_sa(self, F_params, obs: Array, action: Array, task: Task) -> Array:
        """F_k(s, a, w) of the given actions: [2, n, d]."""
        if self.env.discrete:
            F_all = self.forward(F_params, obs, task)                         # [2, n, A, d]
            return jnp.take_along_axis(F_all, action[None, :, None, None], axis=2)[:, :, 0]
        return self.forward(F_params, obs, task, action)

    def policy(self, actor_params, obs: Array, task: Task) -> Array:
        """The actor's action pi(s, w) (continuous actions)."""
        w = jnp.concatenate([task.z, task.h], -1)
        return self.actor_net.apply(actor_params, self.obs_features(obs), w)

    def backward(self, B_params, obs: Array) -> Array:
        """B(s): [..., d], on the sphere of radius sqrt(d)."""
        return self.B_net.apply(B_params, self.obs_features(obs))

    def q_values(self, params: FBParams, obs: Array, task: Task) -> Array:
        """Q(s, a) = min_k F_k(s, a, w)^T z for every discrete action: [..., n_actions]."""
        F = self.forward(params.F, obs, task)
        return jnp.min(jnp.einsum("k...ad,...d->k...a", F, task.z), axis=0)

    # -- protocol ----------------------------------------------------------------------
    def init_fb_params(self, k_F: Array, k_B: Array) -> FBParams:
        """Fresh F (input w = [z; h]) and B parameters; enc left None."""
        obs = self.obs_features(jnp.asarray([self.env.obs_low], jnp.float32))
        w = jnp.zeros((1, self.cfg.d + self.h_dim))
        if self.env.discrete:
            return FBParams(F=self.F_net.init(k_F, obs, w), B=self.B_net.init(k_B, obs))
        k_F, k_actor = jax.random.split(k_F)
        a = jnp.zeros((1, self.env.action_dim))
        return FBParams(F=self.F_net.init(k_F, obs, w, a), B=self.B_net.init(k_B, obs),
                        actor=self.actor_net.init(k_actor, obs, w))

    def init(self, key: Array) -> FBState:
        params = self.init_fb_params(*jax.random.split(key))
        return FBState(params=params, target=params, opt_state=self.optimizer.init(params),
                       step=jnp.zeros((), jnp.int32), average=self.init_average(params))

    def init_average(self, params: FBParams) -> ParamAverage | None:
        """The evaluation average (Config.eval_ema > 0), before any update; else None."""
        if self.cfg.eval_ema == 0:
            return None
        return ParamAverage(params=params.replace(enc=None), n=jnp.zeros((), jnp.int32))

    def eval_params(self, state: FBState) -> FBParams:
        """What acting reads: the online parameters, or with Config.eval_ema > 0 the average
        of F, B and the actor (the encoder, and the statistics set beside it, are the online
        ones: the belief flavours train and freeze them outside the FB update)."""
        if state.average is None:
            return state.params
        return state.average.params.replace(enc=state.params.enc)

    def advance(self, state, params: FBParams, opt_state):
        """The state after one FB update to `params`: targets at rate tau (`update_target`),
        the evaluation average when on, step + 1. `replace`, not a new FBState: the belief
        flavours' states carry extra fields."""
        average = state.average
        if average is not None:
            average = average_update(average, params.replace(enc=None), self.cfg.eval_ema)
        return state.replace(params=params, target=self.update_target(params, state.target),
                             opt_state=opt_state, average=average, step=state.step + 1)

    def update(self, state: FBState, dataset, key: Array, step: Array | None = None,
               stats: dict | None = None) -> tuple[FBState, dict]:
        """One gradient step on a fresh batch sampled from `dataset`.

        step: the global update index (unbatched across seeds); FB does not need it.
        stats: `dataset_stats(dataset)`, computed here if None (`run_steps` computes it
        once per chunk).
        """
        stats = self.dataset_stats(dataset) if stats is None else stats
        k_batch, k_h, k_z, k_aux = jax.random.split(key, 4)
        batch = sample_transitions(k_batch, dataset, self.cfg.batch_size)
        h = self.train_context(state, dataset, batch, k_h)
        z = self.train_z(state, dataset, batch, h, k_z)
        task = Task(z=jax.lax.stop_gradient(z), h=jax.lax.stop_gradient(h))
        aux = self.aux_batch(dataset, batch, k_aux, stats)
        grads, metrics = jax.grad(self.loss, has_aux=True)(state.params, state.target, batch, task, aux)
        params, opt_state = self.apply_grads(state.params, state.opt_state, grads)
        return self.advance(state, params, opt_state), metrics

    def apply_grads(self, params: FBParams, opt_state, grads: FBParams):
        """Clip (Config.clip_norm, global norm over all of F, B, actor), take the Adam step,
        and scale B's step by lr_B / lr (Config.lr_B; Adam is invariant to the gradient's
        scale, so this is Adam on B at lr_B). Neither changes the optimiser state's
        structure, so runs saved before these options existed resume as they were."""
        grads = clip_by_global_norm(grads, self.cfg.clip_norm)
        updates, opt_state = self.optimizer.update(grads, opt_state, params)
        lr_B = self.cfg.lr_B
        b_scale = jnp.where(lr_B > 0, lr_B / self.cfg.lr, 1.0)
        updates = updates.replace(B=jax.tree_util.tree_map(lambda u: u * b_scale, updates.B))
        return optax.apply_updates(params, updates), opt_state

    def run_steps(self, state, dataset, keys: Array, first_step: Array):
        """len(keys) updates as one scan; first_step is the unbatched global step of the first.

        Returns (state, metrics stacked over steps). Agents with training phases override
        this to branch once per chunk rather than once per step.
        """
        steps = first_step + jnp.arange(keys.shape[0])
        stats = self.dataset_stats(dataset)  # once per chunk, not once per update
        return jax.lax.scan(lambda s, xs: self.update(s, dataset, *xs, stats=stats), state, (keys, steps))

    def dataset_stats(self, dataset) -> dict:
        """Constants of the dataset that the loss reads: for Config.splus="exact", "rho"
        [n_states], the frequency of each of the env's states among the dataset's next
        states s_1..s_T (the law rho the measure is a density against); else empty."""
        if self.cfg.splus != "exact":
            return {}
        nxt = dataset.obs[..., 1:, :].reshape(-1, dataset.obs.shape[-1])
        idx = self.env.state_index(nxt)
        counts = jnp.zeros((self.env.num_states,), jnp.float32).at[idx].add(1.0)
        return {"rho": counts / idx.shape[0]}

    def aux_batch(self, dataset, batch: Transitions, key: Array, stats: dict | None = None) -> dict:
        """Extra inputs a loss needs beyond the transitions, as a dict:
        "noise" (continuous actions: the target-policy smoothing noise, already clipped);
        "splus" (Config.splus="states": splus_batch dataset states, independent of the batch);
        "rho" (Config.splus="exact": the weights of env.states(), from `dataset_stats`)."""
        aux = {}
        if self.cfg.splus == "states":  # fold_in: the noise keeps the key it always had
            aux["splus"] = sample_states(jax.random.fold_in(key, 1), dataset, self.cfg.splus_batch)
        elif self.cfg.splus == "exact":
            aux["rho"] = (self.dataset_stats(dataset) if stats is None else stats)["rho"]
        if not self.env.discrete:
            shape = batch.next_obs.shape[:1] + (self.env.action_dim,)
            noise = self.cfg.target_noise * jax.random.normal(key, shape)
            aux["noise"] = jnp.clip(noise, -self.cfg.target_noise_clip, self.cfg.target_noise_clip)
        return aux

    def update_target(self, params: FBParams, target: FBParams) -> FBParams:
        """Polyak averaging: target <- tau * params + (1 - tau) * target."""
        return optax.incremental_update(params, target, self.cfg.tau)

    def loss(self, params: FBParams, target: FBParams, batch: Transitions, task: Task, aux: dict):
        """FB TD loss + ortho_coef * orthonormality loss for one batch.

        The s+ side of the off-diagonal and orthonormality terms (Config.splus):
          "batch":  the batch's own next states, pairs i != j (`fb_loss`, `ortho_loss`);
          "states": aux["splus"], splus_batch dataset states drawn independently of the
                    batch (`fb_loss_splus`, `ortho_loss` on them);
          "exact":  every state of a finite-state env (env.states()) weighted by aux["rho"],
                    its frequency among the dataset's next states: the exact expectation
                    over s+ ~ rho of the same loss, with no s+ sampling variance
                    (`fb_loss_splus` with rho, `ortho_loss_weighted`).
        """
        F = self.forward_sa(params.F, batch.obs, batch.action, task)           # [2, n, d]
        B_next = self.backward(params.B, batch.next_obs)                     # [n, d]
        target_F = self.target_next_F(target, batch.next_obs, task, aux)     # [2, n, d]
        if self.cfg.splus == "batch":
            plus, B_plus = batch.next_obs, B_next
        else:
            plus = aux["splus"] if self.cfg.splus == "states" else self.env.states()
            B_plus = self.backward(params.B, plus)                           # [m, d]
        target_Ms = jnp.einsum("knd,md->knm", target_F, self.backward(target.B, plus))  # [2, n, m]
        # Twin heads (Config.twin_target): their mean (metamotivo's default) or elementwise min
        # (the authors'). min = mean - |Mbar_1 - Mbar_2| / 2 for two heads: a per-step downward
        # bias that the TD recursion amplifies by 1/(1 - gamma) on the off-diagonal measure.
        target_M = jnp.min(target_Ms, 0) if self.cfg.twin_target == "min" else jnp.mean(target_Ms, 0)
        if self.cfg.splus == "batch":
            l_fb, metrics = fb_loss(F, B_next, target_M, self.cfg.gamma)
            l_ortho = ortho_loss(B_next)
        elif self.cfg.splus == "states":
            l_fb, metrics = fb_loss_splus(F, B_next, B_plus, target_M, self.cfg.gamma)
            l_ortho = ortho_loss(B_plus)
        else:
            l_fb, metrics = fb_loss_splus(F, B_next, B_plus, target_M, self.cfg.gamma, aux["rho"])
            l_ortho = ortho_loss_weighted(B_plus, aux["rho"])
        l_actor, m_actor = self.actor_loss(params, batch, task)
        if target_Ms.shape[0] > 1:
            metrics["M_head_gap"] = head_gap(target_Ms, aux.get("rho"), exclude_diag=self.cfg.splus == "batch")
        metrics = dict(metrics, **m_actor, fb_loss=l_fb, ortho_loss=l_ortho,
                       q_mean=jnp.mean(jnp.einsum("knd,nd->kn", F, task.z)))
        total = l_fb + self.cfg.ortho_coef * l_ortho + l_actor
        if not (isinstance(self.cfg.q_loss_coef, float) and self.cfg.q_loss_coef == 0.0):  # traced in a sweep
            l_q = q_loss(F, target_F, B_next, B_plus, task.z, self.cfg.gamma, aux.get("rho"))
            metrics["q_loss"] = l_q
            total = total + self.cfg.q_loss_coef * l_q
        return total, metrics

    def actor_loss(self, params: FBParams, batch: Transitions, task: Task) -> tuple[Array, dict]:
        """Continuous actions, with q_i = min_k F_k(s_i, pi(s_i, w_i), w_i)^T z_i and F frozen
        (stop-gradient), so only the actor moves:
            actor_bc = 0 (the paper):  L = -mean_i q_i
            actor_bc > 0 (TD3+BC):     L = -mean_i q_i / sg(mean_i |q_i|)
                                           + actor_bc * mean_i mean_j (pi(s_i, w_i)_j - a_ij)^2
        with a_i the dataset's action. The second keeps the policy near the behaviour
        data's actions (offline RL's guard against maximising F where it extrapolates; on
        AntWind also against saturated, costly actions the inferred reward cannot see);
        normalising q makes actor_bc scale-free (Fujimoto & Gu 2021; their alpha = 1 / actor_bc).
        Discrete: 0 (the policy is argmax Q)."""
        if self.env.discrete:
            return jnp.zeros(()), {}
        task = jax.lax.stop_gradient(task)  # only the actor learns from -Q (not an encoder via h)
        a = self.policy(params.actor, batch.obs, task)
        F = self.forward(jax.lax.stop_gradient(params.F), batch.obs, task, a)   # [2, n, d]
        q = jnp.min(jnp.einsum("knd,nd->kn", F, task.z), 0)
        if self.cfg.actor_bc == 0:
            return -jnp.mean(q), {"actor_q": jnp.mean(q)}
        bc = jnp.mean((a - batch.action) ** 2)
        q_scale = jax.lax.stop_gradient(jnp.mean(jnp.abs(q))) + 1e-6
        return -jnp.mean(q) / q_scale + self.cfg.actor_bc * bc, {"actor_q": jnp.mean(q), "actor_bc_mse": bc}

    def target_next_F(self, target: FBParams, next_obs: Array, task: Task, aux: dict) -> Array:
        """Fbar(s', a', w) at the target policy's next action(s): [2, n, d].

        Discrete: averaged over the target policy's action probabilities. Continuous:
        a' = clip(pi_target(s', w) + noise, -1, 1) (TD3 target smoothing)."""
        if not self.env.discrete:
            a = jnp.clip(self.policy(target.actor, next_obs, task) + aux["noise"], -1.0, 1.0)
            return self.forward(target.F, next_obs, task, a)
        F_all = self.forward(target.F, next_obs, task)                       # [2, n, A, d]
        q = jnp.min(jnp.einsum("knad,nd->kna", F_all, task.z), axis=0)
        pi = target_policy_weights(q, self.cfg.target_policy, self.cfg.temperature)
        return jnp.einsum("na,knad->knd", jax.lax.stop_gradient(pi), F_all)

    # -- hooks for the Belief/Rotation flavours ---------------------------------------------
    def train_context(self, state, dataset, batch: Transitions, key: Array) -> Array:
        """h for each batch item: FB is context-free, h is empty [n, 0]."""
        return jnp.zeros((batch.obs.shape[0], self.h_dim))

    def train_z(self, state, dataset, batch: Transitions, h: Array, key: Array) -> Array:
        """Training z: uniform on the sqrt(d)-sphere, or with prob z_mix the goal z of a
        random dataset state (`goal_z`)."""
        k_states, k_prior, k_mix = jax.random.split(key, 3)
        n = batch.obs.shape[0]
        z_states = self.goal_z(state.params, batch.obs, sample_states(k_states, dataset, n))
        z_prior = sample_sphere(k_prior, n, self.cfg.d)
        return jax.lax.stop_gradient(mix_z(k_mix, z_prior, z_states, self.cfg.z_mix))

    def goal_z(self, params: FBParams, obs: Array, goal_obs: Array) -> Array:
        """The z that reaches goal_obs from obs: FB's B(goal) (obs unused)."""
        return self.backward(params.B, goal_obs)

    def context_h(self, params: FBParams, context: Context) -> Array:
        """h inferred from one reward-free episode: FB has none."""
        return jnp.zeros((self.h_dim,))

    # -- test time ---------------------------------------------------------------------------
    def goal_task(self, params: FBParams, goal_obs: Array, context: Context) -> Task:
        """Goal reaching: z = B(goal)."""
        return Task(z=self.backward(params.B, goal_obs), h=self.context_h(params, context))

    def reward_task(self, params: FBParams, obs: Array, reward: Array, context: Context) -> Task:
        """Reward inference: z = sqrt(d) * normalize(sum_i r_i B(s_i)); obs [n, obs_dim], reward [n]."""
        z = project_to_sphere(jnp.einsum("n,nd->d", reward, self.backward(params.B, obs)))
        return Task(z=z, h=self.context_h(params, context))

    def act(self, params: FBParams, obs: Array, task: Task, key: Array) -> Array:
        """Discrete: greedy argmax_a min_k F_k(s, a, w)^T z; continuous: the actor pi(s, w)."""
        if not self.env.discrete:
            return self.policy(params.actor, obs, task)
        return jnp.argmax(self.q_values(params, obs, task), axis=-1)
