"""The dynamics-context encoder f_dyn and its self-supervised predictor g.

f_dyn reads a *set* of transitions of one episode, one token per transition, with no
positional encoding, and pools over the unmasked tokens: by their mean, or (pool="max") by
an elementwise max, so that a feature one transition shows, a bump into a wall, is not
diluted by the others. With pool_width = P > 0 each token's features are first mapped
linearly to P channels (a Deep-Sets phi), so the max can keep more separate pieces of
evidence than the embedding has dimensions (a 9x9 map has 81 cells, each seen free or
bumped into). Either way the output is invariant to the order of the transitions
and unaffected by padding. A context of several episodes (Config.context_episodes) is
encoded episode by episode (attention within each) and the pooled features are combined by
an elementwise max over episodes: a feature that any episode shows (a door it passed), the
context shows; invariant to the episodes' order. With pool="cells" (map envs) the pool is by
cell instead: one learned query per map cell attends over every token of the context (all K
episodes at once) and a learned null token (`CellPool`), so each cell's features are read from
the transitions that bear on it, wherever in the layout they are. With pool="evidence" (discrete
map envs) each token says which cell it bears on and what it shows there (`EvidencePool`), two
per-token predictions the encoder loss supervises with targets that are the same in every
layout, and the pool sums that evidence per cell. It returns a diagonal Gaussian
q(h | episode) = N(mu, diag(exp(log_sigma))^2). Everything runs in float32.

g(s_t, a_t, h) regresses s_{t+1}: predicting the next state needs the layout, so h must
carry it.
"""

from __future__ import annotations

from typing import Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp

from zsbfm.nets.mlp import MLP, Dense


class EncoderBlock(nn.Module):
    """Pre-LayerNorm transformer block: masked self-attention then an MLP, residual."""

    embed: int
    heads: int
    mlp: int

    @nn.compact
    def __call__(self, x, mask):
        attn_mask = nn.make_attention_mask(mask, mask)
        y = nn.LayerNorm(dtype=jnp.float32)(x)
        y = nn.MultiHeadDotProductAttention(num_heads=self.heads, dtype=jnp.float32,
                                            param_dtype=jnp.float32)(y, y, mask=attn_mask)
        x = x + y
        y = nn.LayerNorm(dtype=jnp.float32)(x)
        y = Dense(self.embed)(nn.relu(Dense(self.mlp)(y)))
        return x + y


class CellPool(nn.Module):
    """Attention pooling by map cell: x [..., M, E], mask bool[..., M] -> [..., C * P].

    Pooling by multihead attention (the Set Transformer's PMA, Lee et al. 2019) with C learned
    seed queries q_c, one per map cell, over the M unmasked tokens plus one learned null token
    n (always attended, so a cell no transition bears on reads n's value rather than an
    average of unrelated tokens, and an all-masked input is defined):
        y_c = sum_j softmax_j(<W_q q_c, W_k x_j> / sqrt(E / heads)) W_v x_j,  j over tokens and n,
    per head, then W_o. Each y_c is mapped by one Dense shared by all cells to P channels
    (P = width; 0 keeps E) and the C x P features are flattened. A cell's features depend on
    the tokens only through attention weights, so they are invariant to the tokens' order and
    unaffected by masked ones; the query, not the layout, says which cell they describe.
    """

    cells: int
    heads: int
    width: int = 0

    @nn.compact
    def __call__(self, x, mask):
        batch, E = x.shape[:-2], x.shape[-1]
        null = self.param("null", nn.initializers.normal(1.0), (1, E))
        queries = self.param("queries", nn.initializers.normal(1.0), (self.cells, E))
        kv = jnp.concatenate([x, jnp.broadcast_to(null, batch + (1, E))], -2)
        kv_mask = jnp.concatenate([mask, jnp.ones(batch + (1,), bool)], -1)
        attn_mask = nn.make_attention_mask(jnp.ones(batch + (self.cells,), bool), kv_mask)
        y = nn.MultiHeadDotProductAttention(num_heads=self.heads, dtype=jnp.float32, param_dtype=jnp.float32)(
            jnp.broadcast_to(queries, batch + (self.cells, E)), kv, mask=attn_mask)
        if self.width:
            y = Dense(self.width, name="cell_out")(y)
        return y.reshape(batch + (-1,))


class EvidencePool(nn.Module):
    """Pooling of per-token evidence by map cell: x [..., M, E], mask bool[..., M] -> [..., 2C].

    Each token j gives logits over the C map cells, p_j = softmax(W_a x_j + b_a) (the cell
    the transition bears on), and a wall logit e_j = w_e . x_j + b_e (what it shows there).
    Per cell c the evidence of a wall and of free space is summed over the unmasked tokens,
        n_c^wall = sum_j m_j p_jc sigmoid(e_j),   n_c^free = sum_j m_j p_jc (1 - sigmoid(e_j)),
    and the features are [log(1 + n^wall); log(1 + n^free)]. Sums are invariant to the tokens'
    order and unaffected by masked ones. The logits are sown in the "intermediates" collection
    ("cell_logits" [..., M, C], "wall_logit" [..., M]) so that the encoder loss can supervise
    them (agents/belief.py `evidence_loss`): the cell a move points at and that cell's wall
    label are the same function of (s, a, s') in every layout, so, unlike a pool whose
    weights are free, what it learns on train layouts holds on unseen ones. The counts are
    sown too ("n_wall", "n_free" [..., C]), so that h can be read from them (Config.context_read).
    """

    cells: int

    @nn.compact
    def __call__(self, x, mask):
        logits = Dense(self.cells, name="cell_head")(x)
        wall = Dense(1, name="wall_head")(x)[..., 0]
        self.sow("intermediates", "cell_logits", logits)
        self.sow("intermediates", "wall_logit", wall)
        p = jax.nn.softmax(logits, -1) * mask[..., None]
        s = jax.nn.sigmoid(wall)[..., None]
        n_wall, n_free = jnp.sum(p * s, -2), jnp.sum(p * (1.0 - s), -2)
        self.sow("intermediates", "n_wall", n_wall)
        self.sow("intermediates", "n_free", n_free)
        return jnp.concatenate([jnp.log1p(n_wall), jnp.log1p(n_free)], -1)


class ContextEncoder(nn.Module):
    """f_dyn(tokens [..., N, in], mask bool[..., N]) -> (mu, log_sigma), each [..., h_dim].
    With episode_axis: tokens [..., K, N, in], mask [..., K, N] (K episodes; an episode with
    no unmasked token is left out of the max)."""

    h_dim: int
    embed: int = 64
    heads: int = 4
    layers: int = 2
    mlp: int = 128
    pool: str = "mean"   # over an episode's unmasked tokens "mean" | "max"; over the context's, "cells" | "evidence" (zsbfm.names.ENC_POOLS)
    pool_width: int = 0  # P > 0: a linear map of each token (pool="cells": each cell) to P channels
    cells: int = 0       # pool="cells" | "evidence": the number of map cells

    @nn.compact
    def __call__(self, tokens, mask, episode_axis: bool = False):
        x = Dense(self.embed)(tokens.astype(jnp.float32))
        for _ in range(self.layers):
            x = EncoderBlock(self.embed, self.heads, self.mlp)(x, mask)
        x = nn.LayerNorm()(x)
        if self.pool in ("cells", "evidence"):  # one pool over every token of every episode
            if episode_axis:
                x, mask = x.reshape(x.shape[:-3] + (-1, x.shape[-1])), mask.reshape(mask.shape[:-2] + (-1,))
            if self.pool == "cells":
                pooled = CellPool(self.cells, self.heads, self.pool_width)(x, mask)
            else:
                pooled = EvidencePool(self.cells, name="evidence")(x, mask)
            return self.gaussian(pooled)
        if self.pool_width:
            x = Dense(self.pool_width, name="pool_in")(x)
        if self.pool == "max":  # an all-masked episode pools to 0 (and is left out of the max over episodes)
            pooled = jnp.max(jnp.where(mask[..., None], x, -jnp.inf), axis=-2)
            pooled = jnp.where(jnp.any(mask, -1, keepdims=True), pooled, 0.0)
        else:
            w = mask.astype(jnp.float32)[..., None]
            pooled = jnp.sum(x * w, axis=-2) / jnp.maximum(jnp.sum(w, axis=-2), 1.0)
        if episode_axis:  # [..., K, embed] -> [..., embed]
            pooled = jnp.max(jnp.where(jnp.any(mask, -1, keepdims=True), pooled, -jnp.inf), axis=-2)
        return self.gaussian(pooled)

    def gaussian(self, pooled):
        """(mu, log_sigma) of q(h | context), linear in the pooled features."""
        mu = Dense(self.h_dim, name="mu")(pooled)
        log_sigma = jnp.clip(Dense(self.h_dim, name="log_sigma")(pooled), -6.0, 2.0)
        return mu, log_sigma


class Predictor(nn.Module):
    """g(s, a, h) -> predicted next observation (in the normalised observation space)."""

    obs_dim: int
    hidden: Sequence[int]

    @nn.compact
    def __call__(self, obs, action_feat, h):
        return MLP(self.hidden, self.obs_dim)(jnp.concatenate([obs, action_feat, h], -1))
