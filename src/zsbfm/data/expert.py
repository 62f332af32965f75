"""Wind-aware expert data for AntWind: a TD3 expert trained on device, then noisy rollouts.

    params = train_expert(env, ExpertSettings())          # TD3, the true wind as an input
    env    = make_env_for(cfg)                            # zsbfm.data.sources: AntWind + the expert
    data   = load_or_collect_dataset(cfg, env)            # recorded once, cached on disk

The expert is one TD3 agent (Fujimoto et al. 2018) for every train wind: its input is the
AntWind observation (normalised) with (cos, sin) of the wind angle appended, and each of
its `num_envs` vmapped envs runs in a uniformly drawn train wind, redrawn every episode.
Env stepping, the on-device replay buffer and the updates are one `lax.scan` per chunk
(progress between chunks). Why not brax's SAC: brax 0.14's trainer calls
`jax.device_put_replicated`, which JAX 0.10 removed, so it does not run here.

The dataset is then recorded on device with `zsbfm.data.collect`, vmapped over the 15
train winds x episodes: the expert's action plus Gaussian noise (sigma `expert_noise`),
clipped to [-1, 1]. The same noisy expert gives the reward-free context episodes at
evaluation time, in train and held-out winds: the agents see its transitions, never the
wind. `data_policy="random"` records uniformly random actions instead (and random context
episodes).

The preset's expert (seed 0) is trained once and shipped with zsbfm (`experts/`, its actor's
parameters, 300 kB): training it takes ~13 minutes of a 2-core CPU, and shipping it gives
every machine the same expert (training it elsewhere rounds differently, so it makes
different data). `expert_source="train"` trains it here instead, as does any other expert
setting. Experts trained here and datasets are cached under `<data_dir>/antwind/` by a hash
of everything they depend on (`make data ENV=antwind`). To ship another expert: train it
here (`expert_source="train"`), then copy `<data_dir>/antwind/expert-<key>.npz` to
`experts/antwind-expert-<key>.npz`; a test checks that the preset's settings have one.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import tempfile
import time
from typing import Any, Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import struct

from zsbfm.data.dataset import Dataset, load_dataset, save_dataset
from zsbfm.envs.base import num_contexts
from zsbfm.nets.mlp import MLP


@dataclasses.dataclass(frozen=True)
class ExpertSettings:
    """TD3 settings for the wind-conditioned expert (CPU sizes by default)."""

    num_timesteps: int = 1_000_000  # env steps, over all parallel envs
    num_envs: int = 64
    updates_per_iter: int = 8      # gradient steps per parallel env step (of num_envs envs)
    batch_size: int = 256
    lr: float = 3e-4
    gamma: float = 0.97
    tau: float = 0.005
    explore_noise: float = 0.2     # std of the Gaussian exploration noise while training
    target_noise: float = 0.2
    target_noise_clip: float = 0.5
    policy_delay: int = 2
    hidden: tuple[int, ...] = (256, 256)
    warmup: int = 8_192            # uniformly random actions for the first env steps
    chunk_iters: int = 100         # parallel env steps per compiled chunk (progress between)
    seed: int = 0

    @property
    def chunk(self) -> int:
        """Parallel env steps per compiled chunk."""
        return min(self.chunk_iters, -(-self.num_timesteps // self.num_envs))

    @property
    def num_chunks(self) -> int:
        return -(-self.num_timesteps // (self.num_envs * self.chunk))

    @property
    def iters(self) -> int:
        """Parallel env steps in all (num_timesteps rounded up to whole chunks)."""
        return self.num_chunks * self.chunk


def _wind_obs(env, obs, angle):
    """Expert input: the observation normalised as FB's raw encoding, with (cos, sin) of the wind."""
    low, high = jnp.asarray(env.obs_low), jnp.asarray(env.obs_high)
    return jnp.concatenate([2 * (obs - low) / (high - low) - 1, jnp.stack([jnp.cos(angle), jnp.sin(angle)], -1)], -1)


class QNet(nn.Module):
    hidden: Sequence[int]

    @nn.compact
    def __call__(self, x, a):
        q = lambda: MLP(self.hidden, 1)(jnp.concatenate([x, a], -1))[..., 0]
        return jnp.stack([q(), q()])  # twin critics [2, ...]


class PolicyNet(nn.Module):
    action_dim: int
    hidden: Sequence[int]

    @nn.compact
    def __call__(self, x):
        return jnp.tanh(MLP(self.hidden, self.action_dim)(x))


@struct.dataclass
class TD3State:
    actor: Any
    critic: Any
    actor_target: Any
    critic_target: Any
    actor_opt: Any
    critic_opt: Any
    env_state: Any          # EnvState batched over num_envs
    buffer: Any             # dict of [capacity, ...] arrays
    size: jax.Array         # transitions stored
    iteration: jax.Array
    ep_return: jax.Array    # running return of each env's current episode [num_envs]
    last_return: jax.Array  # mean return of the episodes finished most recently
    key: jax.Array


@dataclasses.dataclass(frozen=True)
class TD3Expert:
    """TD3 (Fujimoto et al. 2018) with an on-device replay buffer; one env step of all
    num_envs envs then `updates_per_iter` updates per iteration, all inside `lax.scan`.

    Episodes have no terminal states (AntWind never terminates early), so the TD target
    always bootstraps: y = r + gamma min_k Qbar_k(s', clip(pibar(s') + eps, -1, 1)).
    Each env runs in a uniformly drawn train wind, redrawn at every episode end."""

    env: Any
    settings: ExpertSettings

    @property
    def actor_net(self):
        return PolicyNet(self.env.action_dim, self.settings.hidden)

    @property
    def critic_net(self):
        return QNet(self.settings.hidden)

    @property
    def opt(self):
        return optax.adam(self.settings.lr)

    def _reset_envs(self, key):
        from zsbfm.envs.antwind import wind_angles, wind_context

        angles = jnp.asarray(wind_angles("train"), jnp.float32)
        k_w, k_r = jax.random.split(key)
        ctx = wind_context(angles[jax.random.randint(k_w, (self.settings.num_envs,), 0, angles.shape[0])])
        return jax.vmap(self.env.reset)(jax.random.split(k_r, self.settings.num_envs), ctx)

    def init(self, key) -> TD3State:
        s = self.settings
        k_a, k_c, k_env, k_loop = jax.random.split(key, 4)
        x = jnp.zeros((1, self.env.obs_dim + 2))
        a = jnp.zeros((1, self.env.action_dim))
        actor = self.actor_net.init(k_a, x)
        critic = self.critic_net.init(k_c, x, a)
        cap = s.iters * s.num_envs
        # every leaf strongly typed, as run_chunk returns it: a weak-typed leaf here made the
        # second chunk retrace and recompile (~30 s of MJX compile)
        buffer = {"x": jnp.zeros((cap, self.env.obs_dim + 2)), "a": jnp.zeros((cap, self.env.action_dim)),
                  "r": jnp.zeros((cap,)), "x2": jnp.zeros((cap, self.env.obs_dim + 2))}
        return TD3State(actor=actor, critic=critic, actor_target=actor, critic_target=critic,
                        actor_opt=self.opt.init(actor), critic_opt=self.opt.init(critic),
                        env_state=self._reset_envs(k_env), buffer=buffer, size=jnp.zeros((), jnp.int32),
                        iteration=jnp.zeros((), jnp.int32), ep_return=jnp.zeros((s.num_envs,)),
                        last_return=jnp.full((), jnp.nan, jnp.float32), key=k_loop)

    def act(self, actor, obs, angle):
        return self.actor_net.apply(actor, _wind_obs(self.env, obs, angle))

    def update(self, st: TD3State, key, step):
        s = self.settings
        k_idx, k_noise = jax.random.split(key)
        idx = jax.random.randint(k_idx, (s.batch_size,), 0, st.size)
        b = jax.tree_util.tree_map(lambda v: v[idx], st.buffer)
        noise = jnp.clip(s.target_noise * jax.random.normal(k_noise, b["a"].shape),
                         -s.target_noise_clip, s.target_noise_clip)
        a2 = jnp.clip(self.actor_net.apply(st.actor_target, b["x2"]) + noise, -1.0, 1.0)
        y = b["r"] + s.gamma * jnp.min(self.critic_net.apply(st.critic_target, b["x2"], a2), 0)
        y = jax.lax.stop_gradient(y)
        critic_loss = lambda c: jnp.mean((self.critic_net.apply(c, b["x"], b["a"]) - y[None]) ** 2)
        g, c_opt = jax.grad(critic_loss)(st.critic), st.critic_opt
        upd, c_opt = self.opt.update(g, c_opt)
        critic = optax.apply_updates(st.critic, upd)

        def actor_step(_):
            actor_loss = lambda p: -jnp.mean(self.critic_net.apply(critic, b["x"], self.actor_net.apply(p, b["x"]))[0])
            g_a = jax.grad(actor_loss)(st.actor)
            upd_a, a_opt = self.opt.update(g_a, st.actor_opt)
            actor = optax.apply_updates(st.actor, upd_a)
            return (actor, a_opt, optax.incremental_update(actor, st.actor_target, s.tau),
                    optax.incremental_update(critic, st.critic_target, s.tau))

        def no_actor_step(_):
            return st.actor, st.actor_opt, st.actor_target, st.critic_target

        actor, a_opt, actor_t, critic_t = jax.lax.cond(step % s.policy_delay == 0, actor_step, no_actor_step, None)
        return st.replace(actor=actor, critic=critic, actor_opt=a_opt, critic_opt=c_opt,
                          actor_target=actor_t, critic_target=critic_t)

    def iterate(self, st: TD3State, _):
        """One env step of every env (recorded), then updates_per_iter updates."""
        s = self.settings
        key, k_act, k_rand, k_reset, k_upd = jax.random.split(st.key, 5)
        es = st.env_state
        x = _wind_obs(self.env, es.obs, es.ctx.angle)
        a = jnp.clip(self.actor_net.apply(st.actor, x) + s.explore_noise * jax.random.normal(k_act, (s.num_envs, self.env.action_dim)), -1, 1)
        warm = st.size < s.warmup
        a = jnp.where(warm, jax.random.uniform(k_rand, a.shape, minval=-1, maxval=1), a)
        nxt = jax.vmap(self.env.step)(es, a)
        x2 = _wind_obs(self.env, nxt.obs, nxt.ctx.angle)
        at = st.size + jnp.arange(s.num_envs)
        buffer = {"x": st.buffer["x"].at[at].set(x), "a": st.buffer["a"].at[at].set(a),
                  "r": st.buffer["r"].at[at].set(nxt.reward), "x2": st.buffer["x2"].at[at].set(x2)}
        ep_return = st.ep_return + nxt.reward
        done = nxt.done
        # every env starts at the same step and episodes have a fixed length, so all end
        # together: reset (a vmapped mjx.forward) only then, with a real cond
        env_state = jax.lax.cond(done[0], lambda: self._reset_envs(k_reset), lambda: nxt)
        st = st.replace(env_state=env_state, buffer=buffer, size=st.size + s.num_envs,
                        ep_return=jnp.where(done, 0.0, ep_return),
                        last_return=jnp.where(done[0], jnp.mean(ep_return), st.last_return), key=key)
        keys = jax.random.split(k_upd, s.updates_per_iter)
        steps = st.iteration * s.updates_per_iter + jnp.arange(s.updates_per_iter)
        train = lambda st: jax.lax.fori_loop(0, s.updates_per_iter, lambda i, t: self.update(t, keys[i], steps[i]), st)
        st = jax.lax.cond(st.size >= s.warmup, train, lambda st: st, st)
        return st.replace(iteration=st.iteration + 1), None

    def run_chunk(self, st: TD3State):
        st, _ = jax.lax.scan(self.iterate, st, None, length=self.settings.chunk)
        return st


def train_expert(env, settings: ExpertSettings, progress: bool = True, callback=None):
    """Train the wind-conditioned TD3 expert; returns its actor params. Shows a progress bar
    with the mean return of the latest finished episodes (exploration noise included).
    callback(env_steps, state), if given, runs on the host after every chunk (the state is
    donated to the next chunk: copy what it keeps)."""
    from tqdm.auto import tqdm

    agent = TD3Expert(env, settings)
    st = jax.jit(agent.init)(jax.random.PRNGKey(settings.seed))
    # XLA's default options, not zsbfm.cpu_tuning's: YNNPACK off buys the TD3 loop ~4%
    # (benchmarks/expert_loop.py: 45.3 vs 43.3 ms per iteration), and the shipped expert
    # was trained with the defaults (so expert_source="train" remakes it on the machine
    # that made it; compiled differently, it rounds differently and ends elsewhere)
    chunk = jax.jit(agent.run_chunk, donate_argnums=0)
    bar = tqdm(total=settings.iters * settings.num_envs, disable=not progress,
               unit="step", unit_scale=True, desc="antwind expert (TD3)")
    for _ in range(settings.num_chunks):
        st = chunk(st)
        bar.update(settings.chunk * settings.num_envs)
        bar.set_postfix(episode_return=f"{float(st.last_return):.1f}")
        if callback is not None:
            callback(int(st.size), st)
    bar.close()
    return jax.device_get(st.actor)


@dataclasses.dataclass(frozen=True)
class ExpertBehaviour:
    """The expert as a behaviour policy: a(s, wind) = clip(pi(s, wind) + noise, -1, 1).

    params are held outside hashing/equality (a pytree of arrays), so environments and
    agents carrying this stay hashable. So two of these with different params compare
    equal: never use one as a jit static argument or a cache key."""

    env: Any
    settings: ExpertSettings
    noise: float
    params: Any = dataclasses.field(compare=False, hash=False, repr=False)

    def action(self, key, obs, ctx):
        mode = TD3Expert(self.env, self.settings).act(self.params, obs, ctx.angle)
        return jnp.clip(mode + self.noise * jax.random.normal(key, mode.shape), -1.0, 1.0)


# --- cached on disk -------------------------------------------------------------------------

def expert_settings(cfg) -> ExpertSettings:
    return ExpertSettings(num_timesteps=cfg.expert_steps, seed=cfg.seed)


def _digest(obj) -> str:
    return hashlib.sha1(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()[:10]


def _env_spec(env) -> dict:
    """Everything of the environment a cached expert or dataset depends on."""
    from zsbfm.envs import antwind as aw

    return dict(version=aw.VERSION, episode_len=env.episode_len, wind=aw.WIND_FORCE, n_winds=aw.N_WINDS,
                healthy=(aw.HEALTHY, aw.HEALTHY_Z), ctrl=aw.CTRL_COST, reset=aw.RESET_NOISE,
                frames=aw.FRAME_SKIP)


def _cached(path: str, build, save, load):
    """load(path) if it exists; else process 0 builds and saves it (through a unique
    temporary file, then an atomic rename: never a half-written or clobbered cache) while
    the other processes of a multi-process run wait and then load it."""
    if os.path.exists(path):
        return load(path)
    multi = jax.process_count() > 1
    value = None
    if jax.process_index() == 0:
        value = build()
        os.makedirs(os.path.dirname(path), exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=os.path.dirname(path), suffix=os.path.splitext(path)[1])
        os.close(fd)
        save(tmp, value)
        os.replace(tmp, path)
    if multi:
        from jax.experimental import multihost_utils

        multihost_utils.sync_global_devices(f"zsbfm cache {os.path.basename(path)}")
    return value if value is not None else load(path)


# --- the expert shipped with zsbfm ----------------------------------------------------------

SHIPPED_DIR = os.path.join(os.path.dirname(__file__), "experts")


def expert_key(env, settings: ExpertSettings) -> str:
    """The hash naming an expert: its settings and the environment's constants."""
    return _digest(dict(settings=dataclasses.asdict(settings), env=_env_spec(env)))


def shipped_expert_path(env, settings: ExpertSettings) -> str | None:
    """The expert shipped with zsbfm for exactly these settings and env constants, or None."""
    path = os.path.join(SHIPPED_DIR, f"antwind-expert-{expert_key(env, settings)}.npz")
    return path if os.path.exists(path) else None


def save_expert_npz(path: str, params) -> None:
    """An actor's params (shipped or cached) as an .npz of its leaves, keyed by their
    path in the params ('params/MLP_0/Dense_0/kernel', ...)."""
    from flax import traverse_util

    flat = traverse_util.flatten_dict(jax.device_get(params), sep="/")
    np.savez(path, **{k: np.asarray(v) for k, v in flat.items()})


def load_expert_npz(path: str):
    """The params save_expert_npz wrote (numpy arrays, nested as flax's)."""
    from flax import traverse_util

    with np.load(path) as f:
        return traverse_util.unflatten_dict({k: f[k] for k in f.files}, sep="/")


def expert_origin(env, settings: ExpertSettings, source: str = "shipped") -> str:
    """"shipped" if load_or_train_expert returns the expert shipped with zsbfm, else "trained"."""
    return "shipped" if source == "shipped" and shipped_expert_path(env, settings) else "trained"


def load_or_train_expert(env, settings: ExpertSettings, data_dir: str = "datasets", progress: bool = True,
                         source: str = "shipped"):
    """The expert's actor params: the one shipped with zsbfm for these settings (source=
    "shipped" and one exists), else data_dir/antwind/expert-<hash>.npz (`expert_key`), trained
    here and saved first if missing."""
    shipped = shipped_expert_path(env, settings) if source == "shipped" else None
    if shipped:
        if progress:
            print(f"antwind expert: the one shipped with zsbfm ({os.path.relpath(shipped)}); "
                  "--set expert_source=train trains it here instead")
        return load_expert_npz(shipped)
    path = os.path.join(data_dir, "antwind", f"expert-{expert_key(env, settings)}.npz")

    def build():
        t = time.time()
        params = train_expert(env, settings, progress)
        if progress:
            print(f"expert trained in {time.time() - t:.0f}s -> {path}")
        return params

    return _cached(path, build, save_expert_npz, load_expert_npz)


def with_expert(env, cfg, progress: bool = True):
    """`env` with its behaviour policy attached: the noisy TD3 expert (data_policy="expert",
    shipped, read from the cache or trained) or unchanged, uniform actions ("random")."""
    if cfg.data_policy == "random":
        return env
    settings = expert_settings(cfg)
    params = load_or_train_expert(env, settings, cfg.data_dir, progress, cfg.expert_source)
    return dataclasses.replace(env, behaviour=ExpertBehaviour(env, settings, cfg.expert_noise, params))


def dataset_path(cfg, env) -> str:
    """data_dir/antwind/data-<hash>.npz: the hash of everything cfg's dataset depends on."""
    settings = expert_settings(cfg) if cfg.data_policy == "expert" else None
    spec = dict(policy=cfg.data_policy, episodes=cfg.episodes_per_layout, seed=cfg.seed,
                noise=cfg.expert_noise, env=_env_spec(env),
                expert=dataclasses.asdict(settings) if settings else None,
                # a shipped expert and one trained here may differ in rounding, so their data too
                expert_origin=expert_origin(env, settings, cfg.expert_source) if settings else None)
    return os.path.join(cfg.data_dir, "antwind", f"data-{_digest(spec)}.npz")


def load_or_collect_dataset(cfg, env, progress: bool = True) -> Dataset:
    """The behaviour dataset of `cfg` (all train winds x episodes_per_layout episodes) from
    `dataset_path`, recorded (on device, vmapped) and saved first if missing."""
    from zsbfm.data.collect import collect

    path = dataset_path(cfg, env)

    def build():
        t = time.time()
        key = jax.random.fold_in(jax.random.PRNGKey(cfg.seed), 12345)
        n = cfg.episodes_per_layout
        if progress:
            print(f"recording {n} episodes x {num_contexts(env.contexts('train'))} winds ({cfg.data_policy})...")
        ds = jax.jit(lambda k: collect(env, k, env.contexts("train"), n))(key)
        jax.block_until_ready(ds.obs)
        if progress:
            print(f"{ds.num_transitions} transitions ({cfg.data_policy}) in {time.time() - t:.0f}s -> {path}")
        return ds

    return _cached(path, build, save_dataset, load_dataset)
