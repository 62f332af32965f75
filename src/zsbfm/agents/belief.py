"""Belief-FB and Rotation-FB: FB conditioned on an inferred dynamics context h.

Belief-FB (paper section 3.2, Algorithm 1). A transformer f_dyn infers
q(h | episode) = N(mu, sigma^2) from a set of transitions of one episode. It is trained
self-supervised: a predictor g(s_t, a_t, h) regresses s_{t+1} with h ~ q
(reparameterised), plus beta * KL(q || N(0, I)). F then sees w = [z; h] with
h = stop_gradient(mu) of a window from the *same episode* as the transition; B never
sees h. At test time, h = mu of one reward-free episode in the target layout.

Rotation-FB (section 3.3, Algorithm 2): as Belief-FB, but training z are drawn from
vMF(h / |h|, kappa) scaled to radius sqrt(d) (so dim h = d), mixed with probability
z_mix with B(s), s a state from the same episode as h (Config.rfb_z_states="episode")
or any dataset state ("dataset": the paper's "s ~ D" and the authors' code, as FB).

What F is given as h (Config.h_from): "mu", the standardised mean above (the paper's), or
"context": a head c(mu) regressed on the layout's context features k(layout) (gridworlds:
its interior wall map, the walls oracle's h; agents/oracle.py) with loss
enc_context_coef * mean |c(mu) - k(layout)|^2 added to the encoder's, and h = c(mu). Trained
on the train layouts' features only; at test time h = c(mu(one reward-free episode)), a
prediction of the unseen layout's walls from what the episode saw (least squares: for a
0/1 wall, the probability of a wall given the episode). c is linear, or an MLP with
Config.context_head_hidden; with Config.context_loss="bce" (0/1 features) c gives logits l,
the loss is the mean binary cross-entropy -k log sigmoid(l) - (1 - k) log sigmoid(-l), and
h = sigmoid(l). With h_train_true, F trains on the true features k(layout) instead (the walls
oracle's F) and is given c(mu) only at test time; Config.h_train_mask = p hides each of
those features with probability p (independently per transition and feature), putting the
train layouts' mean feature in its place, so F also learns from maps as incomplete as a
context's. With Config.context_target="revealed" the head's target is instead what the
window itself shows of the layout: k(layout) on the features its transitions reveal
(env.revealed_features: cells entered or bumped into), the train layouts' mean feature
elsewhere. Recalling a train layout's unseen cells then earns nothing, so c can only learn
to read evidence, which an unseen layout also has. With Config.enc_pool="evidence" the
encoder loss also supervises the pool's per-token predictions of which cell a transition
bears on and whether it is a wall (`evidence_loss`), targets that hold in every layout;
with Config.context_read="evidence" h then takes, on the cells the context shows, the
wall fraction of the pool's evidence, and c(mu) only on the others (`read_context`).

Schedules (Config.encoder_mode):
  "staged" (default, the paper's): steps [0, enc_steps) train f_dyn only; at step
    enc_steps the encoder is frozen and mu (and sigma) of every episode's context
    window(s) is computed once into `h_table` [episodes, windows, h_dim]; FB then reads h
    from the table (Config.h_noise: a fresh draw mu + sigma eps per update, as the
    authors' code, which re-runs the frozen encoder on every batch). With context_len = episode_len a window *is* the episode, so the table is exact;
    with shorter contexts it holds `windows_per_episode` random windows per episode.
  "joint": from step 0, every step samples enc_batch episodes, infers h for them with
    gradients, and trains encoder + FB on the sum of both losses, the FB batch drawn
    from those episodes.
Both phases live inside one compiled update (lax.cond), so the training loop is the
same as FB's.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
import optax
from flax import struct

from zsbfm.agents.base import Context, Task
from zsbfm.agents.fb import FBAgent, FBParams, ParamAverage, mix_z
from zsbfm.data.samplers import Transitions, sample_states, sample_windows
from zsbfm.nets.encoder import ContextEncoder, Predictor
from zsbfm.nets.mlp import MLP
from zsbfm.ops.sphere import project_to_sphere
from zsbfm.ops.vmf import sample_vmf

Array = jax.Array


@struct.dataclass
class BeliefState:
    params: FBParams          # F, B and enc = {"encoder": ..., "predictor": ...}
    target: FBParams
    opt_state: Any            # FB optimiser (over all of params; enc gets zero grads when staged)
    step: Array
    enc_opt_state: Any        # encoder pre-training optimiser
    h_table: Array            # [episodes, windows, h_dim] F's h (h_of_mu), filled at step enc_steps (staged)
    h_sigma_table: Array      # [episodes, windows, h_dim] q's sigma on h's scale (read when Config.h_noise)
    average: ParamAverage | None = None  # the evaluation average (Config.eval_ema > 0 only)


@dataclasses.dataclass(frozen=True)
class BeliefFBAgent(FBAgent):
    """Belief-FB. See the module docstring."""

    @property
    def mu_dim(self) -> int:
        """The encoder's q(h | episode) dimension (Config.h_dim, 0 -> d)."""
        return self.cfg.context_dim

    @property
    def h_dim(self) -> int:
        """What F reads: mu_dim, or with h_from="context" the number of context features."""
        if self.cfg.h_from == "context":  # the size of one layout's features (traces nothing)
            one = jax.tree_util.tree_map(lambda x: x[0], self.env.contexts("train"))
            return jax.eval_shape(self.env.context_features, one).shape[-1]
        return self.mu_dim

    @property
    def layout_features(self) -> Array:
        """k(layout) of every train layout: [n_train_layouts, k] (env.context_features)."""
        return jax.vmap(self.env.context_features)(self.env.contexts("train"))

    @property
    def encoder_net(self) -> ContextEncoder:
        c = self.cfg
        return ContextEncoder(self.mu_dim, c.enc_embed, c.enc_heads, c.enc_layers, c.enc_mlp, c.enc_pool,
                              c.enc_pool_width, cells=self.env.n_cells if c.enc_pool in ("cells", "evidence") else 0)

    @property
    def context_head(self) -> nn.Module:
        """c: mu [..., mu_dim] -> [..., h_dim] (logits with context_loss="bce")."""
        hidden = self.cfg.context_head_hidden
        if not hidden:
            return nn.Dense(self.h_dim)  # a linear head keeps the parameter names of saved runs
        return MLP(hidden, self.h_dim, norm_first=False)

    @property
    def predictor_net(self) -> Predictor:
        return Predictor(self.env.obs_dim, self.cfg.pred_hidden)

    @property
    def enc_optimizer(self) -> optax.GradientTransformation:
        return optax.adam(self.cfg.enc_lr)

    @property
    def num_windows(self) -> int:
        return 1 if self.cfg.context_len == self.cfg.episode_len else self.cfg.windows_per_episode

    # -- tokens and inference -----------------------------------------------------------
    def action_features(self, action: Array) -> Array:
        """One-hot for discrete actions (never a float index), as-is for continuous ones."""
        if self.env.discrete:
            return jax.nn.one_hot(action, self.env.n_actions)
        return action

    def tokens(self, obs: Array, action: Array, next_obs: Array) -> Array:
        """One token per transition: [phi(s), a, phi(s'), s' - s] (phi = obs_features,
        s' - s in normalised coordinates): [..., N, token].

        With enc_cell_tokens (pointmass), plus the one-hot of s's map cell: the mean-pooled
        encoder then has the window's cell-visit histogram, the maze's free cells, one linear
        map away; from raw (x, y) alone it did not find the maze (README, Pointmass).
        """
        move = self.normalize_obs(next_obs) - self.normalize_obs(obs)
        parts = [self.obs_features(obs), self.action_features(action), self.obs_features(next_obs), move]
        if self.cfg.enc_cell_tokens:
            parts.append(jax.nn.one_hot(self.env.cell_index(obs), self.env.n_cells))
        return jnp.concatenate(parts, -1)

    def encode(self, enc_params, obs, action, next_obs, mask=None, episodes: bool = False, sown: bool = False):
        """q(h | transitions): (mu, log_sigma), each [..., mu_dim]. obs [..., N, obs_dim];
        with episodes, [..., K, N, obs_dim]: K episodes, combined by the encoder's pool.
        With sown, ((mu, log_sigma), the encoder's "intermediates" collection)."""
        tok = self.tokens(obs, action, next_obs)
        mask = jnp.ones(tok.shape[:-1], bool) if mask is None else mask
        if sown:
            return self.encoder_net.apply(enc_params["encoder"], tok, mask, episodes, mutable=["intermediates"])
        return self.encoder_net.apply(enc_params["encoder"], tok, mask, episodes)

    def standardize(self, enc, mu: Array) -> Array:
        """h = (mu - mean) / std with the dataset statistics of mu frozen at the h-table build.

        The encoder's mu share a large common offset, so raw h / |h| barely differ
        between layouts; standardised h differ in direction (what Rotation-FB's vMF needs)
        and in scale comparable to z inside F's input.
        """
        return (mu - enc["h_mean"]) / enc["h_std"]

    def h_of_mu(self, enc, mu: Array) -> Array:
        """F's h from the encoder's mean [..., mu_dim]: standardised mu, or (h_from="context")
        the head's predicted context features c(mu) [..., k]."""
        if self.cfg.h_from == "context":
            return self.head_features(self.context_head.apply(enc["context_head"], mu))
        return self.standardize(enc, mu)

    def read_context(self, enc, obs: Array, action: Array, next_obs: Array, episodes: bool = False) -> Array:
        """h_from="context": F's h of transitions obs [..., N, d] (with episodes, [..., K, N, d]
        of K episodes): [..., h_dim]. Config.context_read="head": c(mu). "evidence": for each
        map feature j, with n^wall_j and n^free_j the evidence pool's counts at its cell
        (EvidencePool; env.cells_to_features), `evidence_read` of them and c(mu)_j. The counts
        come from the encoder's own per-token predictions, never from the layout."""
        if self.cfg.context_read == "head":
            return self.h_of_mu(enc, self.encode(enc, obs, action, next_obs, episodes=episodes)[0])
        (mu, _), sown = self.encode(enc, obs, action, next_obs, episodes=episodes, sown=True)
        ev = sown["intermediates"]["evidence"]
        n_wall, n_free = (self.env.cells_to_features(ev[k][0]) for k in ("n_wall", "n_free"))
        return self.evidence_read(n_wall, n_free, self.h_of_mu(enc, mu))

    @staticmethod
    def evidence_read(n_wall: Array, n_free: Array, head: Array) -> Array:
        """Where the context shows a cell, n^wall + n^free >= 1/2 (half a transition's evidence
        or more), the wall fraction it shows, n^wall / (n^wall + n^free); elsewhere the head's
        prediction. All [..., k]. A wall map read this way keeps what the context saw even
        where the head, fitted to the train layouts, would recall another layout's cell."""
        seen = n_wall + n_free
        return jnp.where(seen >= 0.5, n_wall / jnp.maximum(seen, 0.5), head)

    def head_features(self, out: Array) -> Array:
        """The context features the head's output c(mu) predicts: sigmoid(c) with
        context_loss="bce" (c are logits), c itself with "mse"."""
        return jax.nn.sigmoid(out) if self.cfg.context_loss == "bce" else out

    def context_mu(self, params: FBParams, context: Context) -> Array:
        """The encoder's mean of the reward-free context: [mu_dim]. context.obs [T+1, d] (one
        episode) or [K, T+1, d] (K episodes)."""
        obs = context.obs
        return self.encode(params.enc, obs[..., :-1, :], context.action, obs[..., 1:, :],
                           episodes=obs.ndim == 3)[0]

    def context_h(self, params: FBParams, context: Context) -> Array:
        """h of the reward-free context: [h_dim]. h_of_mu of its `context_mu`, or with
        h_from="context" `read_context` of its transitions."""
        if self.cfg.h_from == "context":
            obs = context.obs
            return self.read_context(params.enc, obs[..., :-1, :], context.action, obs[..., 1:, :],
                                     episodes=obs.ndim == 3)
        return self.h_of_mu(params.enc, self.context_mu(params, context))

    # -- init ---------------------------------------------------------------------------------
    def init(self, key: Array) -> BeliefState:
        k_F, k_B, k_enc, k_pred, k_head = jax.random.split(key, 5)
        c = self.cfg
        obs = jnp.asarray([self.env.obs_low], jnp.float32)
        feat = self.obs_features(obs)
        a0 = jnp.zeros((1,), jnp.int32) if self.env.discrete else jnp.zeros((1, self.env.action_dim))
        tok = self.tokens(obs[:, None], a0[:, None], obs[:, None])           # [1, 1, token]
        enc = {"encoder": self.encoder_net.init(k_enc, tok, jnp.ones((1, 1), bool)),
               "predictor": self.predictor_net.init(k_pred, feat, self.action_features(a0),
                                                    jnp.zeros((1, self.mu_dim))),
               # statistics of mu, set when the h table is built (identity until then)
               "h_mean": jnp.zeros((self.mu_dim,)), "h_std": jnp.ones((self.mu_dim,))}
        if c.h_from == "context":
            enc["context_head"] = self.context_head.init(k_head, jnp.zeros((1, self.mu_dim)))
        params = self.init_fb_params(k_F, k_B).replace(enc=enc)
        n_ep = c.n_train_layouts * c.episodes_per_layout
        table = jnp.zeros((n_ep, self.num_windows, self.h_dim))
        return BeliefState(params=params, target=params, opt_state=self.optimizer.init(params),
                           step=jnp.zeros((), jnp.int32), enc_opt_state=self.enc_optimizer.init(enc),
                           h_table=table, h_sigma_table=table, average=self.init_average(params))

    # -- encoder pre-training ------------------------------------------------------------------
    def encoder_loss(self, enc, window, target, key, context=None):
        """Predictor MSE + beta KL (+ a contrastive term). window, target: (obs, action,
        next_obs) batches [n, L, ...]; context: int[n], the layout of each window.

        L = mean_{i,t} |g(s_it, a_it, h_i) - s'_it|^2 + beta mean_i KL(N(mu_i, sigma_i^2) || N(0, I)),
        with h_i = mu_i + sigma_i * eps (reparameterised) inferred from window i and the
        regression targets (s, a, s') taken from target i. Also returns mu for reuse.

        With enc_contrast > 0, plus enc_contrast * a supervised InfoNCE over the batch:
        with m_j = mu(target j) and l_ij = -|mu_i - m_j|^2,
            -mean_i log( sum_{j: context_j = context_i} e^{l_ij} / sum_j e^{l_ij} ),
        which pulls together the h of windows of one layout and pushes apart those of
        different layouts (not the paper's: for dynamics that barely change one step, such
        as AntWind's wind under ground contact, the predictor alone need not use h).

        With h_from="context", plus enc_context_coef * mean_{i,j} (c(mu_i) - k(context_i))_j^2,
        the head's regression on the window's layout features (module docstring), or with
        context_loss="bce" their mean binary cross-entropy with c's logits; k is
        `context_target`'s.
        """
        episodes = self.cfg.context_episodes > 1  # windows [n, K, L, ...]: g predicts all K * L
        evidence = self.cfg.enc_pool == "evidence"
        out = self.encode(enc, *window, episodes=episodes, sown=evidence)
        (mu, log_sigma), sown = out if evidence else (out, None)
        h = mu + jnp.exp(log_sigma) * jax.random.normal(key, mu.shape)
        flat = (lambda x: x.reshape((x.shape[0], -1) + x.shape[3:])) if episodes else (lambda x: x)
        mse = self.predictor_mse(enc, h, *map(flat, target))
        kl = jnp.mean(0.5 * jnp.sum(mu**2 + jnp.exp(2 * log_sigma) - 1.0 - 2.0 * log_sigma, -1))
        loss = mse + self.cfg.enc_beta * kl
        metrics = {"enc_mse": mse, "enc_kl": kl, "h_norm": jnp.mean(jnp.linalg.norm(mu, axis=-1))}
        if self.cfg.enc_contrast > 0:
            # target is window (enc_target="episode", joint mode): its mu is already here
            mu_target = mu if target is window else self.encode(enc, *target, episodes=episodes)[0]
            nce = self.contrastive_loss(mu, mu_target, context)
            loss = loss + self.cfg.enc_contrast * nce
            metrics["enc_nce"] = nce
        if self.cfg.h_from == "context":
            out, target_k = self.context_head.apply(enc["context_head"], mu), self.context_target(window, context)
            pred = self.head_features(out)
            ctx_mse = jnp.mean((pred - target_k) ** 2)  # reported either way: comparable across losses
            if self.cfg.context_loss == "bce":
                ctx_loss = jnp.mean(optax.sigmoid_binary_cross_entropy(out, target_k))
                metrics["enc_ctx_bce"] = ctx_loss
            else:
                ctx_loss = ctx_mse
            loss = loss + self.cfg.enc_context_coef * ctx_loss
            metrics["enc_ctx_mse"] = ctx_mse
        if evidence:
            ev_loss, ev_metrics = self.evidence_loss(sown, window, context)
            loss = loss + ev_loss
            metrics.update(ev_metrics)
        return loss, (metrics, mu)

    def evidence_loss(self, sown, window, context: Array):
        """The supervision of the evidence pool's per-token logits (Config.enc_pool="evidence",
        nets/encoder.py EvidencePool). With q_j the cell the move of token j points at
        (env.pointed_cell of its s and a) and y_j that cell's wall label in the window's layout
        (env.cell_walls of context):
            mean_j CE(softmax(cell_logits_j), q_j) + mean_j BCE(sigmoid(wall_logit_j), y_j),
        over the n windows' M = (K *) L tokens, in the encoder's token order. Returns (the
        sum, {"enc_cell_ce", "enc_wall_bce"})."""
        ev = sown["intermediates"]["evidence"]
        cell_logits, wall_logit = ev["cell_logits"][0], ev["wall_logit"][0]   # [n, M, C], [n, M]
        obs, action = window[0], window[1]
        pointed = self.env.pointed_cell(obs, action).reshape(obs.shape[0], -1)   # [n, M]
        walls = jax.vmap(self.env.cell_walls)(self.env.contexts("train"))       # [layouts, C]
        label = walls[context[:, None], pointed]
        ce = jnp.mean(optax.softmax_cross_entropy_with_integer_labels(cell_logits, pointed))
        bce = jnp.mean(optax.sigmoid_binary_cross_entropy(wall_logit, label))
        return ce + bce, {"enc_cell_ce": ce, "enc_wall_bce": bce}

    def context_target(self, window, context: Array) -> Array:
        """What the head c regresses on for each window: [n, h_dim]. k(context) itself
        (Config.context_target="map"), or with "revealed" k(context) where the window's
        transitions (obs, action, next_obs) [n, (K,) L, ...] show it and the train layouts'
        mean feature elsewhere (module docstring)."""
        features = self.layout_features  # a property that computes every layout's map: read once
        if self.cfg.context_target == "map":
            return features[context]
        seen = jax.vmap(self.env.revealed_features)(*window)
        return jnp.where(seen, features[context], features.mean(0))

    def predictor_mse(self, enc, h: Array, obs: Array, action: Array, next_obs: Array) -> Array:
        """mean_{i,t} |g(s_it, a_it, h_i) - s'_it|^2 in normalised units (the paper's
        predictor); h [n, h_dim], obs [n, L, ...]."""
        nxt = self.normalize_obs(next_obs)
        h_tok = jnp.broadcast_to(h[:, None], obs.shape[:2] + h.shape[-1:])
        # g predicts y as s + displacement (normalised units): the same regression of y.
        pred = self.normalize_obs(obs) + self.predictor_net.apply(
            enc["predictor"], self.obs_features(obs), self.action_features(action), h_tok)
        return jnp.mean(jnp.sum((pred - nxt) ** 2, -1))

    @staticmethod
    def contrastive_loss(mu: Array, mu_target: Array, context: Array) -> Array:
        """Supervised InfoNCE of mu [n, h] against mu_target [n, h]; positives share context [n]."""
        logits = -jnp.sum((mu[:, None] - mu_target[None]) ** 2, -1)            # [n, n]
        positive = context[:, None] == context[None]
        log_pos = jax.nn.logsumexp(jnp.where(positive, logits, -jnp.inf), axis=1)
        return jnp.mean(jax.nn.logsumexp(logits, axis=1) - log_pos)

    def context_episodes_of(self, key, episode: Array) -> Array:
        """The episodes of each context: `episode` [n] itself, then context_episodes - 1 other
        episodes of its layout drawn without replacement: int[n, K]. Episodes are
        context-major (episodes_per_layout per layout)."""
        K, per = self.cfg.context_episodes, self.cfg.episodes_per_layout
        if K == 1:
            return episode[:, None]
        draw = lambda k: 1 + jax.random.permutation(k, per - 1)[:K - 1]          # offsets in 1..per-1
        shift = jax.vmap(draw)(jax.random.split(key, episode.shape[0]))      # [n, K-1]
        first = episode - episode % per
        others = first[:, None] + (episode[:, None] % per + shift) % per
        return jnp.concatenate([episode[:, None], others], -1)

    def sample_contexts(self, key, dataset, episode: Array):
        """One context per given episode [n]: a context_len window of the episode itself,
        (obs, action, next_obs) each [n, context_len, ...]; with context_episodes K > 1, one
        of each of its `context_episodes_of` episodes, each [n, K, context_len, ...]."""
        if self.cfg.context_episodes == 1:
            return tuple(sample_windows(key, dataset, episode, self.cfg.context_len))
        k_ep, k_w = jax.random.split(key)
        eps = self.context_episodes_of(k_ep, episode)                          # [n, K]
        return tuple(x.reshape(eps.shape + x.shape[1:])
                     for x in sample_windows(k_w, dataset, eps.reshape(-1), self.cfg.context_len))

    def sample_episode_windows(self, key, dataset, n):
        """n random episodes and one context of each (`sample_contexts`): (episode [n], obs,
        action, next_obs)."""
        k_e, k_w = jax.random.split(key)
        ep = jax.random.randint(k_e, (n,), 0, dataset.num_episodes)
        return (ep,) + self.sample_contexts(k_w, dataset, ep)

    def pretrain_step(self, state: BeliefState, dataset, key) -> tuple[BeliefState, dict]:
        """One encoder step on enc_batch windows; F and B untouched.

        enc_target="episode": g predicts the transitions of the window h was inferred from
        (Algorithm 1). enc_target="context": g predicts a window of *another* episode of the
        same layout (dataset.context_id), so h must carry what episodes of a layout share
        (its walls) rather than what one episode happened to visit.
        """
        k_win, k_other, k_tw, k_eps = jax.random.split(key, 4)
        ep, *window = self.sample_episode_windows(k_win, dataset, self.cfg.enc_batch)
        window = tuple(window)
        if self.cfg.enc_target == "context":
            per = self.cfg.episodes_per_layout  # episodes are context-major
            other = dataset.context_id[ep] * per + jax.random.randint(k_other, ep.shape, 0, per)
            target = self.sample_contexts(k_tw, dataset, other)
        else:
            target = window
        grads, (metrics, _) = jax.grad(self.encoder_loss, has_aux=True)(
            state.params.enc, window, target, k_eps, dataset.context_id[ep])
        updates, enc_opt_state = self.enc_optimizer.update(grads, state.enc_opt_state, state.params.enc)
        enc = optax.apply_updates(state.params.enc, updates)
        params = state.params.replace(enc=enc)
        return state.replace(params=params, target=state.target.replace(enc=enc),
                             enc_opt_state=enc_opt_state, step=state.step + 1), metrics

    def build_h_table(self, state: BeliefState, dataset, key) -> BeliefState:
        """q(h | window) of `num_windows` context windows of every episode, with the frozen
        encoder: h_table = standardised mu, h_sigma_table = sigma / std (Config.h_standardize;
        else mean 0 and std 1: the encoder's own scale). With context_episodes K > 1 each
        window pools a window of the episode and of K - 1 others of its layout
        (`context_episodes_of`). With h_train_true F never reads the table: it stays empty."""
        if self.cfg.h_train_true:
            return state
        L, T, W, K = self.cfg.context_len, dataset.episode_len, self.num_windows, self.cfg.context_episodes
        E = dataset.num_episodes
        from_context = self.cfg.h_from == "context"

        def infer(obs, action, next_obs, episodes=False):
            """What the table holds of a context, and its log sigma: (h, 0) with h_from="context"
            (no sigma on its scale: h_noise is off), else (mu, log sigma)."""
            if from_context:
                h = self.read_context(state.params.enc, obs, action, next_obs, episodes)
                return h, jnp.zeros_like(h)
            return self.encode(state.params.enc, obs, action, next_obs, episodes=episodes)
        if K == 1:
            starts = jax.random.randint(key, (E, W), 0, T - L + 1)
            if W == 1 and L == T:
                starts = jnp.zeros_like(starts)

            def one_episode(args):
                obs, action, st = args
                idx = st[:, None] + jnp.arange(L)[None]                       # [W, L]
                return infer(obs[idx], action[idx], obs[idx + 1])  # 2 x [W, mu_dim] (h_dim: from_context)

            table, log_sigma = jax.lax.stop_gradient(
                jax.lax.map(one_episode, (dataset.obs, dataset.action, starts), batch_size=256))
        else:
            k_st, k_ep = jax.random.split(key)
            eps = self.context_episodes_of(k_ep, jnp.repeat(jnp.arange(E), W)).reshape(E, W, K)
            starts = jax.random.randint(k_st, (E, W, K), 0, T - L + 1)

            def one_context_set(args):
                ep, st = args                                                 # [W, K] each
                idx = st[..., None] + jnp.arange(L)                           # [W, K, L]
                e = ep[..., None]
                return infer(dataset.obs[e, idx], dataset.action[e, idx], dataset.obs[e, idx + 1], episodes=True)

            table, log_sigma = jax.lax.stop_gradient(
                jax.lax.map(one_context_set, (eps, starts), batch_size=max(1, 256 // K)))
        if from_context:
            return state.replace(h_table=table, h_sigma_table=jnp.zeros_like(table))
        if self.cfg.h_standardize:
            enc = dict(state.params.enc, h_mean=table.mean((0, 1)), h_std=table.std((0, 1)) + 1e-6)
        else:
            enc = state.params.enc  # h_mean 0, h_std 1 from init
        return state.replace(params=state.params.replace(enc=enc), target=state.target.replace(enc=enc),
                             h_table=self.standardize(enc, table),
                             h_sigma_table=jnp.exp(log_sigma) / enc["h_std"])

    # -- FB phase hooks ------------------------------------------------------------------------
    def train_context(self, state: BeliefState, dataset, batch: Transitions, key: Array) -> Array:
        """h of a context window from each transition's own episode (from the frozen table):
        its mean, or with Config.h_noise a draw mu + sigma eps, eps ~ N(0, I) per row."""
        if self.cfg.h_train_true:  # F learns from the exact features; c(mu) is its test-time input
            features = self.layout_features  # a property that computes every layout's map: read once
            k = features[dataset.context_id[batch.episode]]
            if self.cfg.h_train_mask:  # as a context that never saw a cell: the train layouts' mean
                hide = jax.random.bernoulli(key, self.cfg.h_train_mask, k.shape)
                k = jnp.where(hide, features.mean(0), k)
            return k
        w = jax.random.randint(key, batch.episode.shape, 0, self.num_windows)
        h = state.h_table[batch.episode, w]
        if self.cfg.h_noise:  # fold_in: the window draw keeps the key it always had
            eps = jax.random.normal(jax.random.fold_in(key, 1), h.shape)
            h = h + state.h_sigma_table[batch.episode, w] * eps
        return h

    # -- the update ----------------------------------------------------------------------------
    # what encoder_loss reports (enc_nce with enc_contrast > 0, enc_ctx_mse with h_from="context",
    # enc_ctx_bce with context_loss="bce", enc_cell_ce and enc_wall_bce with enc_pool="evidence")
    ENCODER_METRICS = ("enc_mse", "enc_kl", "h_norm", "enc_nce", "enc_ctx_mse", "enc_ctx_bce", "enc_cell_ce",
                       "enc_wall_bce")

    @staticmethod
    def _pad(metrics: dict, other_shapes: dict) -> dict:
        """Each phase reports its own metrics; the other phase's entries are zero placeholders
        (both branches of the phase's lax.cond return one structure). Zeros, not NaN, so the
        chunk's finiteness check (zsbfm.nonfinite) reads only real numbers; the host keeps
        the phase's own metrics (`phase_metrics`)."""
        return {**{k: jnp.zeros(v.shape, v.dtype) for k, v in other_shapes.items()}, **metrics}

    def phase_metrics(self, first_step: int, names) -> tuple[str, ...]:
        """The metrics of `names` that a chunk starting at update `first_step` computes: an
        encoder chunk (staged mode, first_step < enc_steps) the encoder's, an FB chunk the
        others; the rest are `_pad`'s placeholders. Joint mode computes them all."""
        if self.cfg.encoder_mode == "joint":
            return tuple(names)
        encoder = first_step < self.cfg.enc_steps
        return tuple(k for k in names if (k in self.ENCODER_METRICS) == encoder)

    def update(self, state: BeliefState, dataset, key: Array, step: Array) -> tuple[BeliefState, dict]:
        """One step: an encoder step while step < enc_steps, else an FB step (the h table is
        built at step enc_steps). `step` must be unbatched across seeds (see
        train.run_chunk). A chunk of one step of `run_steps`, the one mechanism for both."""
        state, metrics = self.run_steps(state, dataset, key[None], step)
        return state, jax.tree_util.tree_map(lambda m: m[0], metrics)

    def run_steps(self, state: BeliefState, dataset, keys: Array, first_step: Array):
        """A chunk of updates, all in one phase (Config checks enc_steps % chunk_steps == 0).

        The phase is chosen once per chunk with lax.cond around a whole scan, rather than
        once per step inside it.
        """
        if self.cfg.encoder_mode == "joint":
            return jax.lax.scan(lambda s, k: self.joint_update(s, dataset, k), state, keys)
        K = self.cfg.enc_steps
        k_table = jax.random.fold_in(keys[0], 1)

        def pre_chunk(s):
            return jax.lax.scan(lambda s, k: self.pretrain_step(s, dataset, k), s, keys)

        def fb_chunk(s):
            s = jax.lax.cond(first_step == K, lambda s: self.build_h_table(s, dataset, k_table),
                             lambda s: s, s)
            stats = self.dataset_stats(dataset)
            return jax.lax.scan(lambda s, k: FBAgent.update(self, s, dataset, k, stats=stats), s, keys)

        pre_shape, fb_shape = jax.eval_shape(pre_chunk, state)[1], jax.eval_shape(fb_chunk, state)[1]

        def pre(s):
            s, m = pre_chunk(s)
            return s, self._pad(m, fb_shape)

        def fb(s):
            s, m = fb_chunk(s)
            return s, self._pad(m, pre_shape)

        return jax.lax.cond(first_step < K, pre, fb, state)

    def joint_update(self, state: BeliefState, dataset, key: Array) -> tuple[BeliefState, dict]:
        """End-to-end: encoder loss + FB loss, gradients of both reach the encoder.

        The FB batch is drawn from the enc_batch episodes whose windows gave h.
        """
        c = self.cfg
        k_win, k_eps, k_tr, k_z, k_aux = jax.random.split(key, 5)
        ep, w_obs, w_act, w_next = self.sample_episode_windows(k_win, dataset, c.enc_batch)
        k_i, k_t = jax.random.split(k_tr)
        which = jax.random.randint(k_i, (c.batch_size,), 0, c.enc_batch)
        t = jax.random.randint(k_t, (c.batch_size,), 0, dataset.episode_len)
        e = ep[which]
        batch = Transitions(obs=dataset.obs[e, t], action=dataset.action[e, t],
                            next_obs=dataset.obs[e, t + 1], episode=e, t=t)

        def total_loss(params):
            window = (w_obs, w_act, w_next)
            l_enc, (m_enc, mu) = self.encoder_loss(params.enc, window, window, k_eps, dataset.context_id[ep])
            h = mu[which]
            z = self.train_z(state.replace(params=params), dataset, batch, jax.lax.stop_gradient(h), k_z)
            aux = self.aux_batch(dataset, batch, k_aux)
            l_fb, m_fb = self.loss(params, state.target, batch, Task(z=jax.lax.stop_gradient(z), h=h), aux)
            return l_fb + l_enc, {**m_fb, **m_enc}

        grads, metrics = jax.grad(total_loss, has_aux=True)(state.params)
        updates, opt_state = self.optimizer.update(grads, state.opt_state, state.params)
        params = optax.apply_updates(state.params, updates)
        return self.advance(state, params, opt_state), metrics


@dataclasses.dataclass(frozen=True)
class RotationFBAgent(BeliefFBAgent):
    """Rotation-FB: training z ~ vMF(h / |h|, kappa) * sqrt(d), mixed with B(s)."""

    def train_z(self, state, dataset, batch: Transitions, h: Array, key: Array) -> Array:
        """z [n, d]: sqrt(d) vMF(h / |h|, kappa), or with prob z_mix B(s) with s a state of
        each row's own episode (Config.rfb_z_states="episode") or any dataset state
        ("dataset", as FB's z). Stop-gradient."""
        k_vmf, k_t, k_mix = jax.random.split(key, 3)
        n = batch.obs.shape[0]
        z_vmf = jnp.sqrt(self.cfg.d) * sample_vmf(k_vmf, h, self.cfg.kappa)
        if self.cfg.rfb_z_states == "dataset":
            states = sample_states(k_t, dataset, n)
        else:
            t = jax.random.randint(k_t, (n,), 1, dataset.episode_len + 1)
            states = dataset.obs[batch.episode, t]
        z_states = self.backward(state.params.B, states)
        return jax.lax.stop_gradient(mix_z(k_mix, z_vmf, z_states, self.cfg.z_mix))
