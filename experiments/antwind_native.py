"""A trained AntWind policy in native MuJoCo (C) beside its MJX return.

    python experiments/antwind_native.py --run runs/antwind-fb-cpu [--seed 0] [--episodes 2]

For every wind (train and test), the run's agent infers h from one reward-free expert
episode in MJX and z from reward-labelled dataset states (exactly as `zsbfm.evaluate`),
then the same policy runs `--episodes` episodes from the same starts both in the MJX env
and in native MuJoCo (mujoco.mj_step, float64, the same model and the wind as the same
torso force). Writes results/antwind_native.json with the per-wind returns and prints the
mean absolute and relative difference. Contact dynamics are chaotic (tests/test_antwind.py:
trajectories agree to float precision until a contact differs), so the comparison is of
returns, not of trajectories.
"""

from __future__ import annotations

import argparse
import json
import os
import time

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from zsbfm.agents import make_agent
from zsbfm.data.collect import rollout
from zsbfm.data.expert import load_or_collect_dataset
from zsbfm.data.sources import make_env_for
from zsbfm.envs import index_contexts
from zsbfm.envs.antwind import CTRL_COST, FRAME_SKIP, TORSO, healthy_bonus, mj_model, observe
from zsbfm.evaluate import context_episode, reward_states
from zsbfm.run import load


def native_return(m, qpos, qvel, force, act, length: int) -> float:
    """Return of `act` (obs -> action) over `length` env steps in native MuJoCo."""
    d = mujoco.MjData(m)
    d.qpos[:], d.qvel[:] = qpos, qvel
    mujoco.mj_forward(m, d)
    dt = m.opt.timestep * FRAME_SKIP
    total = 0.0
    for _ in range(length):
        a = np.clip(np.asarray(act(observe(jnp.asarray(d.qpos, jnp.float32), jnp.asarray(d.qvel, jnp.float32)))), -1, 1)
        x0 = d.qpos[0]
        d.ctrl[:] = a
        d.xfrc_applied[TORSO, :3] = force
        for _ in range(FRAME_SKIP):
            mujoco.mj_step(m, d)
        total += ((d.qpos[0] - x0) / dt + float(healthy_bonus(d.qpos[2]))
                  - CTRL_COST * float(np.sum(a ** 2)))
    return total


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--run", default="runs/antwind-fb-cpu")
    p.add_argument("--seed", type=int, default=0, help="which of the run's seeds")
    p.add_argument("--episodes", type=int, default=2, help="episodes per wind")
    p.add_argument("--out", default="results/antwind_native.json")
    a = p.parse_args()
    run = load(a.run)
    cfg = run.cfg
    if cfg.env != "antwind":
        raise SystemExit(f"--run {a.run} is a {cfg.env!r} run; this script compares antwind policies")
    env = make_env_for(cfg)
    agent = make_agent(cfg, env)
    params = run.seed_params(a.seed)
    reward_obs = reward_states(jax.random.PRNGKey(1), load_or_collect_dataset(cfg, env))
    m = mj_model()
    act_jit = jax.jit(lambda obs, task: agent.act(params, obs, task, jax.random.PRNGKey(0)))

    @jax.jit
    def mjx_episode(key, ctx, task):
        k_reset, k_roll = jax.random.split(key)
        start = env.reset(k_reset, ctx)
        _, _, reward = rollout(env, key, ctx, lambda k, obs: agent.act(params, obs, task, k), cfg.eval_episode_len)
        return start.inner.qpos, start.inner.qvel, jnp.sum(reward)

    rows = []
    t0 = time.time()
    for split in ("train", "test"):
        ctxs = env.contexts(split)
        for i in range(int(ctxs.angle.shape[0])):
            ctx = index_contexts(ctxs, i)
            k_ctx, k_eps = jax.random.split(jax.random.PRNGKey(100 + i))
            context = context_episode(env, k_ctx, ctx, cfg.context_len)
            task = agent.reward_task(params, reward_obs, env.state_reward(reward_obs), context)
            for k in jax.random.split(k_eps, a.episodes):
                # rollout() resets with the first half of its key: the same start in both
                qpos, qvel, ret_mjx = mjx_episode(k, ctx, task)
                ret_native = native_return(m, np.asarray(qpos, np.float64), np.asarray(qvel, np.float64),
                                           np.asarray(ctx.force, np.float64), lambda o: act_jit(o, task),
                                           cfg.eval_episode_len)
                rows.append({"split": split, "wind": float(ctx.angle), "mjx": float(ret_mjx), "native": ret_native})
                print(f"{split} wind {np.degrees(float(ctx.angle)):5.0f} deg: MJX {float(ret_mjx):8.1f}  "
                      f"native {ret_native:8.1f}", flush=True)
    mjx_r, nat_r = np.array([r["mjx"] for r in rows]), np.array([r["native"] for r in rows])
    summary = {"run": a.run, "seed": a.seed, "episodes": len(rows), "mean_mjx": float(mjx_r.mean()),
               "mean_native": float(nat_r.mean()), "mean_abs_diff": float(np.abs(mjx_r - nat_r).mean()),
               "corr": float(np.corrcoef(mjx_r, nat_r)[0, 1]), "seconds": round(time.time() - t0, 1)}
    os.makedirs(os.path.dirname(a.out) or ".", exist_ok=True)
    with open(a.out, "w") as f:
        json.dump({"summary": summary, "episodes": rows}, f, indent=2)
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
