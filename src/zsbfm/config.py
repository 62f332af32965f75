"""Run configuration: one frozen dataclass, presets per (env, algo, size), validated early.

`Config.preset(env, algo)` gives the CPU preset (sized to finish on a 2-core machine);
`Config.preset(env, algo, size="paper")` gives the paper's GPU sizes (Table 4), and
size="authors" the settings of the authors' public code (gridworlds). Every
value is checked in `__post_init__`, so a bad value fails with the field's name before
anything is traced or compiled. Use `dataclasses.replace(cfg, field=value)` to change a
field (it re-validates).
"""

from __future__ import annotations

import dataclasses
import json
from typing import Any

import zsbfm.envs  # noqa: F401  (registers the built-in environments)
from zsbfm.envs.registry import env_names, env_spec
# the names of every choice live below config (zsbfm.names); re-exported here for callers
from zsbfm.names import (ALGOS, BELIEF_ALGOS, DATA_POLICIES, ENCODER_MODES, EXPERT_SOURCES,  # noqa: F401
                         CONTEXT_LOSSES, CONTEXT_READS, CONTEXT_TARGETS, ENC_POOLS, F_ARCHS, H_FROM, OBS_ENCODINGS, ON_NONFINITE, RFB_Z_STATES, SIZES, SPLUS,
                         TARGET_POLICIES, TWIN_TARGETS, algo_names)

ENVS = env_names()                     # the environments registered at import (zsbfm.envs.registry)
# Float settings a vmapped sweep can vary inside one compiled program (zsbfm.sweep): each is
# only ever used as a number in the traced code (no Python branch reads it). Any other field
# changes shapes or control flow, so each of its values compiles a program of its own.
SWEEPABLE = ("lr", "lr_B", "q_loss_coef", "tau", "gamma", "temperature", "ortho_coef", "z_mix", "clip_norm",
             "kappa", "enc_lr", "enc_beta", "feat_tau", "feat_gamma", "hilp_expectile",
             "hilp_p_traj_goal", "target_noise", "target_noise_clip")
# Integer settings where 0 is allowed, with what 0 means (every other integer size is > 0).
NONNEGATIVE_INTS = {"eval_every": "chunks; 0: evaluate only at the end",
                    "enc_layers": "0: per-token embedding, then pooled",
                    "h_dim": "0 means d",
                    "enc_pool_width": "0: pool the token embedding itself"}


def _is_int(v) -> bool:
    """An int and not a bool (True would otherwise pass as 1)."""
    return isinstance(v, int) and not isinstance(v, bool)


@dataclasses.dataclass(frozen=True)
class Config:
    # --- what to run ---------------------------------------------------------------------
    env: str = "fourrooms"      # environment: one of ENVS (zsbfm.make_env)
    algo: str = "fb"            # algorithm: one of ALGOS (zsbfm.agents)
    size: str = "cpu"           # which preset the sizes came from: "cpu", "long" (gridworlds) or "paper" (GPU)
    name: str = ""              # run name; "" -> "<env>-<algo>-<size>"
    seed: int = 0               # master seed; seed i of the sweep uses split(PRNGKey(seed))[i]
    num_seeds: int = 3          # seeds trained together with jax.vmap
    runs_dir: str = "runs"      # runs are written to runs_dir/name/

    # --- data ------------------------------------------------------------------------------
    n_train_layouts: int = 20   # train contexts (layouts, mazes; antwind: its 15 train winds)
    episodes_per_layout: int = 500  # behaviour episodes collected in each train context
    episode_len: int = 100      # must equal the environment's episode length
    context_len: int = 100      # transitions per context window (belief methods)
    # behaviour episodes of one layout per context (belief methods), in training and at test time:
    # the encoder reads context_len transitions of each, max-pooled over episodes (1: the paper's)
    context_episodes: int = 1
    # antwind only: the behaviour data (zsbfm.data.expert), cached under data_dir/antwind/
    data_policy: str = "expert"  # "expert": the noisy wind-aware TD3 expert | "random"
    # env steps of TD3 training for the expert (the preset's is shipped: expert_source): 300k
    # steps returned 244 / 236 on train / test winds, 1M 476 / 530, 2M 582 / 670 (docs/results.md)
    expert_steps: int = 2_000_000
    expert_noise: float = 0.2    # std of the Gaussian noise on the expert's actions in the data
    # "shipped": the expert that comes with zsbfm (zsbfm/data/experts/) when one was trained
    # with these expert settings (the preset's, seed 0), else trained here | "train": trained here
    expert_source: str = "shipped"
    data_dir: str = "datasets"   # where cached datasets and experts live (antwind)
    # a saved dataset (.npz: obs, action, context_id; zsbfm.data.dataset) shared by every seed;
    # "" = the env's own data (collected per seed on device; antwind: its cached expert data)
    dataset: str = ""

    # --- FB -----------------------------------------------------------------------------
    # network input: "onehot" (one-hot of each grid coordinate) | "raw" (coordinates scaled
    # to [0, 1]) | "unscaled" (the observation as the env emits it: the authors' input)
    obs_encoding: str = "onehot"
    d: int = 50                               # latent dimension of z, F, B
    f_pre_hidden: tuple[int, ...] = (128,)    # preprocessor hidden layers
    f_pre_out: int = 128                      # preprocessor output width
    f_hidden: tuple[int, ...] = (256,)        # F trunk hidden layers
    f_arch: str = "reference"                 # F's layers: "reference" | "normed_trunk" | "mlp" (also B's; nets/fb.py)
    b_hidden: tuple[int, ...] = (128, 128)    # B hidden layers
    f_heads: int = 2                          # independent F heads: 2 = twin F (min for the policy), 1 = single
    # the twin heads' target measure: "mean" of Mbar_k (metamotivo) | elementwise "min" (the
    # authors' code; biased down by half the heads' gap, agents/fb.py FBAgent.loss)
    twin_target: str = "mean"
    lr: float = 1e-3                          # Adam learning rate of F, B (and actor / features)
    batch_size: int = 256                     # transitions per update
    gamma: float = 0.95                       # paper: 0.99 (docs/experiments.md: 10k-20k CPU updates cannot propagate its horizon)
    tau: float = 0.05                         # Polyak rate of the target networks (paper's Table 4: 0.05; the authors' code: 0.01)
    z_mix: float = 0.5                        # probability that a training z is B(s)
    ortho_coef: float = 1.0                   # weight of B's orthonormality loss
    target_policy: str = "greedy"             # "greedy" | "boltzmann" | "uniform"
    temperature: float = 1.0                  # Boltzmann target-policy temperature
    # s+ side of the off-diagonal and orthonormality terms (agents/fb.py FBAgent.loss):
    # "batch" (the batch's next states, i != j) | "states" (splus_batch independent dataset
    # states) | "exact" (every state of a finite-state env, weighted by its data frequency)
    splus: str = "batch"
    splus_batch: int = 1024                   # states per update for splus="states"
    clip_norm: float = 0.0                    # global gradient-norm clip of F/B/actor (0: none)
    lr_B: float = 0.0                         # B's learning rate (0: lr)
    q_loss_coef: float = 0.0                  # weight of the TD loss on Q = F^T z itself (agents/fb.py q_loss; 0: off)
    eval_ema: float = 0.0                     # evaluate an average of F/B/actor at this rate, over about 1/eval_ema updates (agents/fb.py ParamAverage; 0: the online parameters)

    # --- continuous actions (pointmass): TD3-style actor ------------------------------------
    actor_hidden: tuple[int, ...] = (256, 256)  # actor MLP hidden layers
    target_noise: float = 0.2        # std of the target-policy smoothing noise
    target_noise_clip: float = 0.3   # clip of that noise
    actor_bc: float = 0.0            # TD3+BC weight: 0 = the paper's pure -Q actor (agents/fb.py)

    # --- Belief-FB / Rotation-FB (ignored by fb) -------------------------------------------
    h_dim: int = 0               # dimension of the encoder's mu (F's h unless h_from="context"); 0 -> d (rfb needs h_dim = d)
    h_in_sa: bool = False        # h also enters F's (s, a) preprocessor (paper: only with z)
    h_noise: bool = False        # FB trains on h ~ q(h | episode) = mu + sigma eps, a fresh draw per update (the authors'); False: mu
    h_standardize: bool = True   # h standardised by the dataset statistics of mu (agents/belief.py); False: the encoder's own scale
    # what F is given as h: "mu" (the paper's: the encoder's mean) | "context" (bfb: a linear
    # head's prediction of the layout's context features from mu, trained on the train layouts;
    # for gridworlds the wall map, the walls oracle's input inferred from one episode)
    h_from: str = "mu"
    enc_context_coef: float = 1.0  # weight of that head's regression loss (h_from="context")
    h_train_true: bool = False   # h_from="context": F trains on the train layouts' true features (the walls oracle's h), c(mu) only at test
    h_train_mask: float = 0.0    # h_train_true: each training feature is hidden (the train layouts' mean stands in) with this probability
    context_head_hidden: tuple[int, ...] = ()  # h_from="context": hidden ReLU layers of the head c; () = linear
    context_loss: str = "mse"    # h_from="context": the head's loss, "mse" | "bce" (0/1 features: c gives logits, h = sigmoid)
    context_target: str = "map"  # h_from="context": the head regresses on the layout's "map" | what the context "revealed" of it
    context_read: str = "head"   # h_from="context": h = c(mu) ("head"), or on the cells the context shows, its evidence ("evidence")
    enc_embed: int = 32          # transformer width
    enc_heads: int = 4           # attention heads per block
    enc_layers: int = 2          # transformer blocks (0: each token's linear embedding is pooled)
    enc_mlp: int = 64            # width of each block's MLP
    # pooling of an episode's tokens (nets/encoder.py): "mean" (the paper's) | "max" (elementwise) |
    # "cells" (one attention query per map cell, over every episode's tokens) | "evidence" (each
    # token's supervised cell and wall / free evidence, summed per cell over every episode's tokens)
    enc_pool: str = "mean"
    enc_pool_width: int = 0      # P > 0 (enc_pool="max" | "cells"): each token (each cell) mapped linearly to P channels (0: the embedding's)
    pred_hidden: tuple[int, ...] = (64, 64)     # predictor g(s, a, h) -> s'
    enc_lr: float = 1e-3         # Adam learning rate of the encoder pre-training
    enc_beta: float = 1e-6       # weight of KL(q(h | episode) || N(0, I)) in the encoder loss
    enc_contrast: float = 0.0    # weight of a same-layout InfoNCE on h (agents/belief.py; 0 = paper)
    enc_cell_tokens: bool = False  # tokens also hold the one-hot map cell of s (pointmass, gridworlds; agents/belief.py)
    enc_steps: int = 4_000       # K: encoder pre-training steps before FB (staged mode)
    enc_batch: int = 16          # episodes (context windows) per encoder batch
    enc_target: str = "context"  # predict the window's own transitions, or another episode's of its layout ("context")
    encoder_mode: str = "staged"  # "staged": f_dyn first, then FB on stop_grad(h); "joint"
    windows_per_episode: int = 4  # h-table windows per episode when context_len < episode_len
    kappa: float = 50.0          # vMF concentration of Rotation-FB's training z
    # Rotation-FB's B(s) half of the training z: s from h's own "episode" | any "dataset" state
    # (the paper's and the authors'; on Four-Rooms the goal cells' z, far from the episode)
    rfb_z_states: str = "episode"
    oracle_context: str = "id"   # what the oracle's F is told: "id" (one-hot train layout) | "walls" (agents/oracle.py)

    # --- successor-feature baselines: HILP, Laplacian (ignored by the FB family) ---------
    feat_hidden: tuple[int, ...] = (128, 128)  # phi(s) network
    feat_tau: float = 0.005      # Polyak rate of phi's target (HILP)
    feat_gamma: float = 0.99     # discount of HILP's goal-conditioned value -|phi(s) - phi(g)|
    hilp_expectile: float = 0.5  # IQL expectile of HILP's value loss (paper: 0.5 zero-shot, 0.95 GC)
    hilp_p_traj_goal: float = 0.625  # P(goal = future state of the same episode); else random

    # --- schedule -------------------------------------------------------------------------
    steps: int = 10_000          # gradient steps per seed (belief algos: enc_steps more)
    chunk_steps: int = 1_000     # steps per compiled chunk (progress/metrics/checkpoint)
    checkpoint: bool = True      # write an orbax checkpoint after every chunk
    # a seed whose losses or parameters go non-finite (NaN, inf): "stop" the run with a one-line
    # error, its last finite checkpoint kept | "drop" the seed, marked in metrics.jsonl,
    # results.json and the plots, and train the others on (zsbfm/nonfinite.py). A policy, not
    # part of the run: a stopped run may resume with the other value
    on_nonfinite: str = "stop"

    # --- devices (placement only: results equal up to float summation order) --------------
    data_parallel: int = 1       # size of the "data" mesh axis each seed's batch is split over

    # --- evaluation ------------------------------------------------------------------------
    eval_episode_len: int = 100  # steps of each evaluation episode
    eval_every: int = 0          # chunks between learning-curve evaluations (0: only at the end)
    eval_protocols: str = "all"  # "all": every protocol of the env (paper, dense, ...) | "official"

    def __post_init__(self):
        def bad(field, value, allowed):
            raise ValueError(f"Config.{field}={value!r} is invalid: expected {allowed}")

        if self.env not in env_names():
            bad("env", self.env, f"one of {env_names()}")
        spec = env_spec(self.env)
        if self.algo not in algo_names():  # built-in and registered (zsbfm.agents.register_agent)
            bad("algo", self.algo, f"one of {algo_names()}")
        if self.size not in SIZES:
            bad("size", self.size, f"one of {SIZES}")
        if self.obs_encoding not in OBS_ENCODINGS:
            bad("obs_encoding", self.obs_encoding, f"one of {OBS_ENCODINGS}")
        if self.twin_target not in TWIN_TARGETS:
            bad("twin_target", self.twin_target, f"one of {TWIN_TARGETS}")
        if self.enc_target not in ("episode", "context"):
            bad("enc_target", self.enc_target, "'episode' or 'context'")
        if self.encoder_mode not in ENCODER_MODES:
            bad("encoder_mode", self.encoder_mode, f"one of {ENCODER_MODES}")
        if self.f_arch not in F_ARCHS:
            bad("f_arch", self.f_arch, f"one of {F_ARCHS}")
        if self.data_policy not in DATA_POLICIES:
            bad("data_policy", self.data_policy, f"one of {DATA_POLICIES}")
        if self.expert_source not in EXPERT_SOURCES:
            bad("expert_source", self.expert_source, f"one of {EXPERT_SOURCES}")
        if self.expert_noise < 0:
            bad("expert_noise", self.expert_noise, "expert_noise >= 0")
        if spec.fixed_train and self.n_train_layouts != spec.n_train:
            bad("n_train_layouts", self.n_train_layouts,
                f"{spec.n_train} for {self.env} (its train contexts are fixed)")
        if spec.max_train is not None and self.n_train_layouts > spec.max_train:
            bad("n_train_layouts", self.n_train_layouts,
                f"at most {spec.max_train} for {self.env} (the rest of its contexts are held out for test)")
        if self.on_nonfinite not in ON_NONFINITE:
            bad("on_nonfinite", self.on_nonfinite, f"one of {ON_NONFINITE}")
        if self.eval_protocols not in ("all", "official"):
            bad("eval_protocols", self.eval_protocols, "'all' or 'official'")
        if self.oracle_context not in ("id", "walls"):
            bad("oracle_context", self.oracle_context, "'id' or 'walls'")
        if self.splus not in SPLUS:
            bad("splus", self.splus, f"one of {SPLUS}")
        if self.splus == "exact" and not spec.finite_states:
            bad("splus", self.splus, f"'batch' or 'states' for the continuous env {self.env!r} "
                "('exact' sums over a finite state set)")
        if not 0.0 <= self.eval_ema < 1.0:
            bad("eval_ema", self.eval_ema, "0 <= eval_ema < 1 (0: evaluate the online parameters)")
        if not self.clip_norm >= 0:
            bad("clip_norm", self.clip_norm, "clip_norm >= 0 (0: no clipping)")
        if not self.q_loss_coef >= 0:
            bad("q_loss_coef", self.q_loss_coef, "q_loss_coef >= 0 (0: off)")
        if not self.lr_B >= 0:
            bad("lr_B", self.lr_B, "lr_B >= 0 (0: the same as lr)")
        if self.target_policy not in TARGET_POLICIES:
            bad("target_policy", self.target_policy, f"one of {TARGET_POLICIES}")
        for f in ("num_seeds", "n_train_layouts", "episodes_per_layout", "episode_len",
                  "context_len", "d", "f_pre_out", "batch_size", "steps", "chunk_steps",
                  "eval_episode_len", "enc_embed", "enc_heads", "enc_mlp",
                  "enc_steps", "enc_batch", "windows_per_episode", "splus_batch",
                  "f_heads", "expert_steps"):
            v = getattr(self, f)
            if not _is_int(v) or v <= 0:
                bad(f, v, "a positive integer")
        for f, zero in NONNEGATIVE_INTS.items():
            v = getattr(self, f)
            if not _is_int(v) or v < 0:
                bad(f, v, f"a non-negative integer ({zero})")
        if self.enc_embed % self.enc_heads:
            bad("enc_embed", self.enc_embed, f"a multiple of enc_heads={self.enc_heads}")
        if self.enc_lr <= 0:
            bad("enc_lr", self.enc_lr, "enc_lr > 0")
        if self.enc_beta < 0:
            bad("enc_beta", self.enc_beta, "enc_beta >= 0")
        if self.enc_contrast < 0:
            bad("enc_contrast", self.enc_contrast, "enc_contrast >= 0")
        if self.enc_pool not in ENC_POOLS:
            bad("enc_pool", self.enc_pool, f"one of {ENC_POOLS}")
        if self.enc_pool_width and self.enc_pool in ("mean", "evidence"):
            bad("enc_pool_width", self.enc_pool_width,
                f"0 with enc_pool={self.enc_pool!r} (mean: a linear map before a mean folds into mu's own; evidence: "
                "its features are fixed, 2 per cell; use enc_pool='max' or 'cells')")
        if self.enc_pool == "cells" and not spec.cell_map:
            bad("enc_pool", self.enc_pool, f"'mean' or 'max' for env={self.env!r} (it has no cell map of positions: EnvSpec.cell_map)")
        if self.enc_pool == "evidence" and not spec.pointed_cells:
            bad("enc_pool", self.enc_pool, f"'mean' or 'max' for env={self.env!r} (it has no cell a move points at: "
                "EnvSpec.pointed_cells)")
        if self.enc_cell_tokens and not spec.cell_map:
            bad("enc_cell_tokens", self.enc_cell_tokens,
                f"False for env={self.env!r} (it has no cell map of positions: EnvSpec.cell_map)")
        if not self.kappa > 0:
            bad("kappa", self.kappa, "kappa > 0")
        if self.rfb_z_states not in RFB_Z_STATES:
            bad("rfb_z_states", self.rfb_z_states, f"one of {RFB_Z_STATES}")
        if self.h_from not in H_FROM:
            bad("h_from", self.h_from, f"one of {H_FROM}")
        if self.h_from == "context":
            if self.algo != "bfb":
                bad("h_from", self.h_from, f"'mu' for algo={self.algo!r} ('context' is Belief-FB's only)")
            if self.encoder_mode != "staged" or self.h_noise:
                bad("h_from", self.h_from, "'mu' here: 'context' needs encoder_mode='staged' and "
                    f"h_noise=False (got {self.encoder_mode!r}, {self.h_noise}): it reads the frozen encoder's mean")
            if not self.enc_context_coef > 0:
                bad("enc_context_coef", self.enc_context_coef,
                    "enc_context_coef > 0 with h_from='context' (0 leaves the head c(mu) untrained)")
        if self.context_loss not in CONTEXT_LOSSES:
            bad("context_loss", self.context_loss, f"one of {CONTEXT_LOSSES}")
        if any(w <= 0 for w in self.context_head_hidden):
            bad("context_head_hidden", self.context_head_hidden, "positive widths")
        if self.h_from != "context" and (self.context_head_hidden or self.context_loss != "mse"):
            bad("h_from", self.h_from, "'context' with context_head_hidden or context_loss set (they shape its head)")
        if self.context_loss == "bce" and not spec.binary_context:
            bad("context_loss", self.context_loss,
                f"'mse' for env={self.env!r} (its context features are not 0/1: EnvSpec.binary_context)")
        if self.context_target not in CONTEXT_TARGETS:
            bad("context_target", self.context_target, f"one of {CONTEXT_TARGETS}")
        if self.context_read not in CONTEXT_READS:
            bad("context_read", self.context_read, f"one of {CONTEXT_READS}")
        if self.context_read == "evidence" and (self.h_from != "context" or self.enc_pool != "evidence"):
            bad("context_read", self.context_read, "'head' unless h_from='context' and enc_pool='evidence' (it reads "
                f"the evidence pool's counts into the head's map; got h_from={self.h_from!r}, enc_pool={self.enc_pool!r})")
        if self.context_target == "revealed" and self.h_from != "context":
            bad("context_target", self.context_target, "'map' unless h_from='context' (it is the head's target)")
        if self.context_target == "revealed" and not spec.revealed_context:
            bad("context_target", self.context_target, f"'map' for env={self.env!r} (it does not say what a "
                "context reveals of its features: EnvSpec.revealed_context)")
        if self.h_train_true and self.h_from != "context":
            bad("h_train_true", self.h_train_true, "False unless h_from='context' (it replaces c(mu) in training)")
        if not 0.0 <= self.h_train_mask < 1.0:
            bad("h_train_mask", self.h_train_mask, "a probability in [0, 1)")
        if self.h_train_mask and not self.h_train_true:
            bad("h_train_mask", self.h_train_mask, "0 unless h_train_true=True (it hides part of the true features)")
        if not self.enc_context_coef >= 0:
            bad("enc_context_coef", self.enc_context_coef, "enc_context_coef >= 0")
        if self.algo == "rfb" and self.h_dim not in (0, self.d):
            bad("h_dim", self.h_dim, f"0 or d={self.d} for rfb (z is drawn around h/|h| in R^d)")
        if not 0.0 < self.feat_tau <= 1.0:
            bad("feat_tau", self.feat_tau, "0 < feat_tau <= 1")
        if not 0.0 < self.feat_gamma < 1.0:
            bad("feat_gamma", self.feat_gamma, "0 < feat_gamma < 1")
        if not 0.0 < self.hilp_expectile < 1.0:
            bad("hilp_expectile", self.hilp_expectile, "0 < hilp_expectile < 1")
        if not 0.0 <= self.hilp_p_traj_goal <= 1.0:
            bad("hilp_p_traj_goal", self.hilp_p_traj_goal, "0 <= hilp_p_traj_goal <= 1")
        if self.steps % self.chunk_steps:
            bad("steps", self.steps, f"a multiple of chunk_steps={self.chunk_steps}")
        if self.algo in BELIEF_ALGOS and self.encoder_mode == "staged":
            if self.enc_steps >= self.steps:
                bad("enc_steps", self.enc_steps, f"fewer than steps={self.steps} (FB trains after it; "
                    f"e.g. enc_steps={max(self.chunk_steps, self.steps * 2 // 7 // self.chunk_steps * self.chunk_steps)})")
            if self.enc_steps % self.chunk_steps:
                bad("enc_steps", self.enc_steps,
                    f"a multiple of chunk_steps={self.chunk_steps} (no chunk straddles two phases)")
        for f in ("f_pre_hidden", "f_hidden", "b_hidden", "pred_hidden", "feat_hidden", "actor_hidden"):
            v = getattr(self, f)
            if not isinstance(v, tuple) or not v or any(not isinstance(h, int) or h <= 0 for h in v):
                bad(f, v, "a non-empty tuple of positive integers")
        if not 0.0 < self.gamma < 1.0:
            bad("gamma", self.gamma, "0 < gamma < 1")
        if not 0.0 < self.tau <= 1.0:
            bad("tau", self.tau, "0 < tau <= 1")
        if not 0.0 <= self.z_mix <= 1.0:
            bad("z_mix", self.z_mix, "0 <= z_mix <= 1")
        if not self.lr > 0:
            bad("lr", self.lr, "lr > 0")
        if self.ortho_coef < 0:
            bad("ortho_coef", self.ortho_coef, "ortho_coef >= 0")
        if not self.temperature > 0:
            bad("temperature", self.temperature, "temperature > 0")
        if self.batch_size < 2:
            bad("batch_size", self.batch_size, "batch_size >= 2 (the FB loss pairs batch items)")
        if not spec.discrete and self.obs_encoding == "onehot":
            bad("obs_encoding", self.obs_encoding, f"'raw' or 'unscaled' for the continuous env {self.env!r} (one-hot needs a grid)")
        if not self.actor_bc >= 0:
            bad("actor_bc", self.actor_bc, "actor_bc >= 0 (0 disables the behaviour-cloning term)")
        if self.actor_bc > 0 and spec.discrete:
            bad("actor_bc", self.actor_bc, f"0 for the discrete env {self.env!r} (no actor: pi = argmax Q)")
        if self.target_noise < 0 or self.target_noise_clip < 0:
            bad("target_noise", (self.target_noise, self.target_noise_clip), "non-negative noise and clip")
        if self.episode_len != spec.episode_len:
            bad("episode_len", self.episode_len, f"{spec.episode_len} for env {self.env!r}")
        if self.context_len > self.episode_len:
            bad("context_len", self.context_len,
                f"at most the episode length ({self.episode_len}): a context is one episode's window")
        if not isinstance(self.context_episodes, int) or isinstance(self.context_episodes, bool) \
                or not 1 <= self.context_episodes <= self.episodes_per_layout:
            bad("context_episodes", self.context_episodes,
                f"an integer in 1..episodes_per_layout={self.episodes_per_layout} (episodes of one layout per context)")
        if self.context_episodes > 1 and self.algo not in BELIEF_ALGOS:
            bad("context_episodes", self.context_episodes, f"1 for algo={self.algo!r} (only belief methods read a context)")
        if not isinstance(self.data_parallel, int) or isinstance(self.data_parallel, bool) or self.data_parallel <= 0:
            bad("data_parallel", self.data_parallel, "a positive integer (devices per seed's batch)")
        if self.batch_size % self.data_parallel:
            bad("data_parallel", self.data_parallel,
                f"a divisor of batch_size={self.batch_size} (each device of the 'data' mesh axis "
                "takes batch_size / data_parallel transitions)")

    # -- derived --------------------------------------------------------------------------
    @property
    def run_name(self) -> str:
        return self.name or f"{self.env}-{self.algo}-{self.size}"

    @property
    def context_dim(self) -> int:
        """Dimension of the context: the encoder's mu for bfb/rfb (F's h, unless Belief-FB's
        h_from="context"), the number of train layouts for oracle (a one-hot layout index), 0
        for context-free algorithms."""
        if self.algo == "oracle" and self.oracle_context == "id":
            return self.n_train_layouts
        return (self.h_dim or self.d) if self.algo in BELIEF_ALGOS else 0

    @property
    def fb_steps(self) -> int:
        """Updates of the main optimiser: steps, less the encoder pre-training of staged belief runs."""
        staged = self.algo in BELIEF_ALGOS and self.encoder_mode == "staged"
        return self.steps - (self.enc_steps if staged else 0)

    @property
    def num_chunks(self) -> int:
        return self.steps // self.chunk_steps

    # -- presets and (de)serialisation -----------------------------------------------------
    @staticmethod
    def preset(env: str = "fourrooms", algo: str = "fb", size: str = "cpu", **overrides) -> "Config":
        """The preset for (env, algo, size), with `overrides` applied on top.

        size="cpu": the default, sized for a 2-core CPU (minutes per seed).
        size="paper": the paper's GPU sizes (Table 4: d=100 discrete, F (1024, 1024),
        B (256, 256, 256), batch 1024, lr 1e-4, 1M steps); hours on a GPU.
        size="authors": the settings of the authors' public code (gridworlds only).
        size="long": the gridworlds' longer CPU preset.
        """
        if size not in SIZES:
            raise ValueError(f"Config.size={size!r} is invalid: expected one of {SIZES}")
        base: dict[str, Any] = dict(env=env, algo=algo, size=size)
        for k in overrides:
            if k in REMOVED_FIELDS:
                raise ValueError(removed_option_error(k, overrides[k]))
        spec = env_spec(env)  # the env module's own preset overrides (zsbfm.envs.registry)
        if size not in spec.presets:
            raise ValueError(f"Config.size={size!r} is invalid for env {env!r}: expected one of {tuple(spec.presets)}")
        base.update(spec.presets[size])
        if algo in BELIEF_ALGOS:  # the encoder phase comes on top of the FB steps
            base.update(_BELIEF_PRESETS[size])
            base.update(spec.belief_presets.get(size, {}))
        base.update(spec.algo_presets.get(size, {}).get(algo, {}))
        if algo in BELIEF_ALGOS + ("oracle",) and size in ("cpu", "long"):
            # h also enters F's (s, a) preprocessor: with h only beside z, F barely used even
            # the true layout id (oracle, 4 layouts: 0.17 train success; with h_in_sa: 0.42).
            base.update(h_in_sa=True)
        if algo == "random":  # nothing to train: one no-op chunk
            base.update(steps=base.get("chunk_steps", 1_000))
        if algo in BELIEF_ALGOS and "steps" in overrides and "enc_steps" not in overrides:
            # a shorter (longer) belief run keeps the preset's share of encoder steps,
            # rounded down to whole chunks (at least one)
            chunk = overrides.get("chunk_steps", base.get("chunk_steps", Config.chunk_steps))
            share = base.get("enc_steps", Config.enc_steps) / base.get("steps", Config.steps)
            base["enc_steps"] = max(chunk, int(overrides["steps"] * share) // chunk * chunk)
        base.update(overrides)
        return Config(**base)

    def replace(self, **changes) -> "Config":
        """dataclasses.replace(self, **changes): a new, validated Config."""
        return dataclasses.replace(self, **changes)

    def with_traced(self, values: dict) -> "Config":
        """A copy with the scalar fields in `values` set to (traced) arrays, without
        validation: for the inside of a vmapped sweep, whose every value was validated as a
        concrete Config first (zsbfm.sweep). Only `SWEEPABLE` fields may be set."""
        bad = sorted(set(values) - set(SWEEPABLE))
        if bad:
            raise ValueError(f"fields {bad} cannot be traced: the sweepable fields are {SWEEPABLE}")
        new = object.__new__(Config)
        for f in dataclasses.fields(self):
            object.__setattr__(new, f.name, values.get(f.name, getattr(self, f.name)))
        return new

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @staticmethod
    def from_dict(d: dict) -> "Config":
        fields = {f.name: f for f in dataclasses.fields(Config)}
        d = dict(d)
        for k, (kept, _) in REMOVED_FIELDS.items():  # saved at the one value that remains: drop
            if k in d and (value := d.pop(k)) != kept:
                raise ValueError(removed_option_error(k, value))
        for k, (values, _) in REMOVED_VALUES.items():
            if d.get(k) in values:
                raise ValueError(removed_option_error(k, d[k]))
        unknown = set(d) - set(fields)
        if unknown:
            raise ValueError(f"unknown Config fields {sorted(unknown)}")
        d = {**LEGACY_DEFAULTS, **d}
        return Config(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.items()})

    def with_overrides(self, overrides: list[str] | tuple[str, ...]) -> "Config":
        """Apply "field=value" strings (CLI form); tuples are comma-separated ints."""
        fields = {f.name: f for f in dataclasses.fields(Config)}
        changes: dict[str, Any] = {}
        for item in overrides:
            if "=" not in item:
                raise ValueError(f"override {item!r} must look like field=value")
            k, v = item.split("=", 1)
            if k in REMOVED_FIELDS:
                raise ValueError(removed_option_error(k, v))
            if k not in fields:
                raise ValueError(f"unknown Config field {k!r}; fields: {', '.join(fields)}")
            current = getattr(self, k)
            try:
                if isinstance(current, bool):
                    if v.lower() not in ("true", "false", "1", "0"):
                        raise ValueError(v)
                    changes[k] = v.lower() in ("true", "1")
                elif isinstance(current, tuple):
                    changes[k] = tuple(int(x) for x in v.split(",") if x)
                else:
                    changes[k] = type(current)(float(v) if isinstance(current, int) and "e" in v else v)
            except ValueError:
                raise ValueError(f"Config.{k}: cannot parse {v!r} as {type(current).__name__}") from None
        return dataclasses.replace(self, **changes)

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2)


# Fields whose default changed: a saved config without the field ran with the old value.
LEGACY_DEFAULTS: dict[str, Any] = {"f_arch": "normed_trunk"}
# twin_target was a removed option between c971d54 and its return (size="authors"): a config
# saved then lacks it and ran with "mean", the default.

# Options no preset used and no table showed better, removed from the code (their
# measurements: docs/experiments.md, "Removed options"; the code: commit REMOVED_IN's parent).
# A saved config.json that holds a removed field at the value that remains loads as before;
# one that used a removed option is a one-line error.
REMOVED_IN = "c971d54"
REMOVED_FIELDS: dict[str, tuple[Any, str]] = {  # field: (the value that remains, what it was)
    "h_cond": ("concat", "how h conditioned F: FiLM or the outer product"),
    "lr_schedule": ("constant", "a cosine learning-rate schedule"),
    "enc_pred_horizon": (1, "the predictor regressing the mean of the next k states"),
}
REMOVED_VALUES: dict[str, tuple[tuple, str]] = {"obs_encoding": (("cell",), "a one-hot of the grid cell")}


def removed_option_error(field: str, value) -> str:
    what = REMOVED_FIELDS.get(field, REMOVED_VALUES.get(field))[1]
    return (f"Config.{field}={value!r} is a removed option ({what}): the run needs zsbfm at commit "
            f"{REMOVED_IN} or earlier (docs/experiments.md, 'Removed options')")

_BELIEF_PRESETS: dict[str, dict[str, Any]] = {
    "cpu": dict(enc_steps=4_000, steps=14_000),
    "long": dict(enc_steps=4_000, steps=44_000),
    "paper": dict(enc_steps=10_000, steps=1_010_000, enc_embed=128, enc_mlp=256,
                  pred_hidden=(256, 256, 256), enc_lr=1e-4),
    "authors": {},  # each env that has the size sets its encoder (envs/gridworld.py)
}
