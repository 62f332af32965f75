"""AntWind on MuJoCo MJX: the MuJoCo Ant running forward under a constant wind.

Model: brax's `ant.xml` (the Gymnasium Ant geometry: 8 motors of gear 150, timestep
0.01), with brax's MJX solver settings (Newton, 1 iteration, 4 line-search iterations,
Euler damping off) and one change: the torso sphere also collides with the floor, so an
ant that flips rests on its back instead of falling through the floor (episodes never
terminate early, see below). One env step = `FRAME_SKIP` = 5 physics steps (dt 0.05).

Wind: a constant world-frame horizontal force of `WIND_FORCE` newtons on the torso,
written into `mjx.Data.xfrc_applied` at every step (not MuJoCo's fluid model: that needs
non-zero fluid parameters when the model is put on device, is costlier on this CPU stack
and is not implemented with `implicitfast`; a force is the same for every wind, so one
compiled step serves every wind under `vmap`). The wind is the context pytree
`WindContext(angle, force)`; 20 directions evenly spaced on the circle, angle_i = 2 pi i / 20.
Train: the first three quadrants (angles in [0, 3 pi / 2): 15 winds); test: the last
(5 winds). The paper used 16 / 4 with the fluid model (magnitude 4, viscosity 0.05).

Observation (27): qpos[2:] (torso height, torso quaternion, 8 joint angles) and qvel (14:
torso linear and angular velocity, 8 joint velocities); x and y are left out (the task is
translation invariant) and so is the wind (the hidden dynamics context).

Reward ("run forward" along +x; Gymnasium's Ant terms, with a healthy range from 0.3, not
0.2: an ant resting on its back has its torso at 0.25):
    r = (x_after - x_before) / dt  +  HEALTHY * [HEALTHY_Z[0] < z < HEALTHY_Z[1]]  -  CTRL_COST * |a|^2
`state_reward(obs)` is the action-free part as a function of the next observation (qvel_x
for the forward velocity), the reward that zero-shot agents infer z from. Episodes are
`episode_len` = 256 steps with no early termination (a fixed length keeps every episode of
the dataset the same shape; an unhealthy ant simply earns no healthy bonus).

Torso height is read from qpos[2], never from `Data.xpos` (see REFERENCE.md: computing it
from brax's `pipeline_state.x.pos` costs ~100x on this CPU stack).
"""

from __future__ import annotations

import dataclasses
import functools
import os
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from zsbfm.envs.base import EnvBase, EnvState
from zsbfm.envs.registry import EnvSpec, register

Array = jax.Array

VERSION = 1               # bump on any change of the dynamics: cached experts/datasets key on it
FRAME_SKIP = 5
N_WINDS = 20
N_TRAIN_WINDS = 15        # the first three quadrants train, the last is held out
WIND_FORCE = 2.0          # newtons on the torso (the ant weighs about 9 N; see the tests)
HEALTHY = 1.0
HEALTHY_Z = (0.3, 1.0)
CTRL_COST = 0.5
RESET_NOISE = 0.1
OBS_DIM = 27


@struct.dataclass
class WindContext:
    """One wind. angle: float32[] (radians); force: float32[3], the world-frame force on the torso."""

    angle: Array
    force: Array


def wind_context(angle) -> WindContext:
    angle = jnp.asarray(angle, jnp.float32)
    force = WIND_FORCE * jnp.stack([jnp.cos(angle), jnp.sin(angle), jnp.zeros_like(angle)], -1)
    return WindContext(angle=angle, force=force)


def wind_angles(split: str) -> np.ndarray:
    """The fixed wind directions of a split: train = [0, 3 pi / 2), test = [3 pi / 2, 2 pi)."""
    angles = 2 * np.pi * np.arange(N_WINDS) / N_WINDS
    train = angles < 1.5 * np.pi - 1e-6
    return angles[train] if split == "train" else angles[~train]


@functools.lru_cache(maxsize=None)
def mj_model():
    """The native MuJoCo model (mujoco.MjModel) with the settings above."""
    import brax
    import mujoco

    path = os.path.join(os.path.dirname(brax.__file__), "envs", "assets", "ant.xml")
    m = mujoco.MjModel.from_xml_path(path)
    m.opt.solver = mujoco.mjtSolver.mjSOL_NEWTON
    m.opt.iterations = 1
    m.opt.ls_iterations = 4
    m.opt.disableflags = m.opt.disableflags | mujoco.mjtDisableBit.mjDSBL_EULERDAMP
    m.geom_contype[m.geom("torso_geom").id] = 1  # the torso collides with the floor
    return m


@functools.lru_cache(maxsize=None)
def mjx_model():
    from mujoco import mjx

    # concrete arrays even when first called inside a jit trace (the cache outlives it)
    with jax.ensure_compile_time_eval():
        return mjx.put_model(mj_model())


TORSO = 1  # body id of the torso (0 is the world)


def observe(qpos: Array, qvel: Array) -> Array:
    return jnp.concatenate([qpos[..., 2:], qvel], -1)


def healthy_bonus(z: Array) -> Array:
    """HEALTHY while the torso height z is inside HEALTHY_Z (open interval), else 0."""
    return HEALTHY * ((z > HEALTHY_Z[0]) & (z < HEALTHY_Z[1])).astype(jnp.float32)


def state_reward(obs: Array) -> Array:
    """The action-free reward of arriving in `obs`: forward velocity + healthy bonus ([...])."""
    return obs[..., 13] + healthy_bonus(obs[..., 0])  # qvel_x, torso z


@dataclasses.dataclass(frozen=True)
class AntWind(EnvBase):
    """AntWind (see the module docstring). Hashable: the MJX model is a module-level cache."""

    episode_len: int = 256
    # the behaviour policy of data and context episodes: an object with action(key, obs, ctx)
    # (zsbfm.data.expert.ExpertBehaviour), or None for uniform random actions
    behaviour: Any = dataclasses.field(default=None, compare=False, hash=False, repr=False)

    name = "antwind"
    discrete = False
    obs_dim = OBS_DIM
    n_actions = 0
    action_dim = 8
    metric = "return"
    # bounds for input normalisation only (not enforced): z, quaternion, 8 joints, 14 velocities
    obs_low = (0.0,) + (-1.0,) * 4 + (-1.5,) * 8 + (-10.0,) * 14
    obs_high = (1.5,) + (1.0,) * 4 + (1.5,) * 8 + (10.0,) * 14

    def __post_init__(self):
        if self.episode_len < 1:
            raise ValueError(f"episode_len must be >= 1, got {self.episode_len}")

    @property
    def dt(self) -> float:
        return float(mj_model().opt.timestep) * FRAME_SKIP

    # -- contexts ---------------------------------------------------------------------------
    def contexts(self, split: str) -> WindContext:
        if split not in ("train", "test"):
            raise ValueError(f"split must be 'train' or 'test', got {split!r}")
        return wind_context(wind_angles(split))

    def context_features(self, ctx: WindContext) -> Array:
        """The wind as a vector (the oracle's "walls" context): (cos, sin) of its direction times its force."""
        return ctx.force[..., :2]

    def sample_contexts(self, key: Array, n: int) -> WindContext:
        """n winds of uniformly random direction in the train range [0, 3 pi / 2) (jittable)."""
        return wind_context(jax.random.uniform(key, (n,), maxval=1.5 * jnp.pi))

    # -- dynamics ---------------------------------------------------------------------------
    def reset(self, key: Array, ctx: WindContext, goal: Array | None = None,
              start: Array | None = None) -> EnvState:
        """Standing at the origin (root position and orientation exact), joint angles
        perturbed by U(-RESET_NOISE, RESET_NOISE), velocities by N(0, RESET_NOISE^2) (goal
        and start are not used: AntWind's task is a reward)."""
        from mujoco import mjx

        m = mjx_model()
        k_q, k_v = jax.random.split(key)
        qpos0 = jnp.asarray(mj_model().qpos0, jnp.float32)
        qpos = qpos0.at[7:].add(jax.random.uniform(k_q, (8,), minval=-RESET_NOISE, maxval=RESET_NOISE))
        qvel = RESET_NOISE * jax.random.normal(k_v, (m.nv,))
        data = mjx.forward(m, mjx.make_data(m).replace(qpos=qpos, qvel=qvel))
        return EnvState(obs=observe(data.qpos, data.qvel), reward=jnp.zeros((), jnp.float32),
                        done=jnp.zeros((), bool), t=jnp.zeros((), jnp.int32),
                        goal=jnp.zeros(OBS_DIM, jnp.float32), has_goal=jnp.zeros((), bool),
                        ctx=ctx, inner=data)

    def physics(self, data, action: Array, force: Array):
        """FRAME_SKIP MJX steps with ctrl = action and the wind force on the torso."""
        from mujoco import mjx

        m = mjx_model()
        data = data.replace(ctrl=action, xfrc_applied=data.xfrc_applied.at[TORSO, :3].set(force))
        return jax.lax.fori_loop(0, FRAME_SKIP, lambda _, d: mjx.step(m, d), data)

    def step(self, state: EnvState, action: Array) -> EnvState:
        action = jnp.clip(jnp.asarray(action, jnp.float32), -1.0, 1.0)
        data = self.physics(state.inner, action, state.ctx.force)
        obs = observe(data.qpos, data.qvel)
        reward = ((data.qpos[0] - state.inner.qpos[0]) / self.dt + healthy_bonus(data.qpos[2])
                  - CTRL_COST * jnp.sum(action ** 2))
        t = state.t + 1
        return state.replace(obs=obs, reward=reward.astype(jnp.float32), done=t >= self.episode_len,
                             t=t, inner=data)

    def random_action(self, key: Array) -> Array:
        return jax.random.uniform(key, (8,), minval=-1.0, maxval=1.0)

    def state_reward(self, obs: Array) -> Array:
        """The reward zero-shot agents infer z from (see `state_reward`)."""
        return state_reward(obs)

    def behaviour_policy(self, ctx: WindContext):
        """policy(key, obs) of the behaviour in wind ctx (the expert sees the wind, the
        agents never do), or uniform random actions without an expert."""
        if self.behaviour is None:
            return lambda key, obs: self.random_action(key)
        return lambda key, obs: self.behaviour.action(key, obs, ctx)


def _make(n_train: int = N_TRAIN_WINDS, episode_len: int = 256) -> AntWind:
    return AntWind(episode_len=episode_len)


# 15 train winds x 100 expert episodes x 256 steps = 384k transitions; contexts are 100-step
# windows; returns over 256-step episodes.
register(EnvSpec(
    name="antwind", make=_make, episode_len=256, discrete=False, n_train=N_TRAIN_WINDS, fixed_train=True,
    expert_behaviour=True, shares_data=True,
    presets={
        # TD3+BC actor (agents/fb.py): the pure -Q actor pushed saturated, costly actions off
        # the expert data (FB, 3 seeds: return -124 / -131 train / test with actor_bc=0,
        # 224 / 197 with 0.4; docs/results.md)
        "cpu": dict(n_train_layouts=N_TRAIN_WINDS, episodes_per_layout=100, episode_len=256,
                    eval_episode_len=256, context_len=100, obs_encoding="raw", gamma=0.98, steps=10_000,
                    actor_bc=0.4, f_arch="normed_trunk"),
        "paper": dict(n_train_layouts=N_TRAIN_WINDS, episodes_per_layout=1000, episode_len=256,
                      eval_episode_len=256, context_len=100, obs_encoding="raw", expert_steps=3_000_000,
                      d=150, f_pre_hidden=(1024,), f_pre_out=512, f_hidden=(1024, 1024),
                      b_hidden=(256, 256, 256), actor_hidden=(1024, 1024), lr=1e-4, batch_size=1024,
                      gamma=0.99, tau=0.05, steps=1_000_000, chunk_steps=10_000, kappa=100.0,
                      feat_hidden=(512, 512))},
    # A same-wind InfoNCE on h (agents/belief.py, not the paper's): the wind barely changes
    # one step under ground contact, so the predictor alone never used h (wind probe error
    # 28 deg -> 10 deg; h PCA coherence 0.32 -> 0.78; Rotation-FB test return 201 -> 262).
    belief_presets={"cpu": dict(enc_contrast=1.0)},
    description="MuJoCo Ant under a constant wind (MJX)"))
