"""The AntWind TD3 expert's learning curve: train it (zsbfm.data.expert, not cached) and every
`--every` env steps score the noise-free policy on the train and held-out winds (4 episodes
per wind, the keys of experiments/antwind_expert.py), with the training time so far.

    python experiments/antwind_expert_curve.py [--every 100000] [--set hidden="(128, 128)" num_timesteps=600000]
        [--save DIR]

--set overrides ExpertSettings fields (Python literals). Prints one line per point; --save
writes the actor at each point as DIR/actor-<env steps>.npz (zsbfm.data.expert.save_expert_npz).
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import os
import time

import jax

import zsbfm
from zsbfm.data.collect import behaviour_returns
from zsbfm.data.expert import ExpertBehaviour, ExpertSettings, TD3Expert, save_expert_npz


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--every", type=int, default=100_000)
    p.add_argument("--set", nargs="*", default=[], help="ExpertSettings overrides, field=value")
    p.add_argument("--save", default="", help="directory for the actor's params at each point")
    a = p.parse_args()
    fields = {f.name for f in dataclasses.fields(ExpertSettings)}
    over = {}
    for item in a.set:
        k, _, v = item.partition("=")
        if k not in fields:
            raise SystemExit(f"--set {k}: not an ExpertSettings field (one of {sorted(fields)})")
        over[k] = ast.literal_eval(v)
    s = ExpertSettings(**over)
    env = zsbfm.make_env("antwind")
    agent = TD3Expert(env, s)
    st = jax.jit(agent.init)(jax.random.PRNGKey(s.seed))
    chunk = jax.jit(agent.run_chunk, donate_argnums=0)  # as train_expert compiles it

    @jax.jit
    def returns(params):
        """Mean noise-free return on the train and the test winds (antwind_expert.py's keys)."""
        e = dataclasses.replace(env, behaviour=ExpertBehaviour(env, s, 0.0, params))
        return [behaviour_returns(e, jax.random.PRNGKey(3), e.contexts(split), 4).mean() for split in ("train", "test")]

    seconds, per_chunk = 0.0, s.chunk * s.num_envs
    print(f"ExpertSettings overrides {over}")
    for i in range(s.num_chunks):
        t = time.perf_counter()
        st = jax.block_until_ready(chunk(st))
        seconds += time.perf_counter() - t
        done = (i + 1) * per_chunk
        if done // a.every != (done - per_chunk) // a.every or i == s.num_chunks - 1:
            train, test = (float(r) for r in returns(st.actor))
            if a.save:
                os.makedirs(a.save, exist_ok=True)
                save_expert_npz(os.path.join(a.save, f"actor-{done}.npz"), st.actor)
            print(f"{done:>9,} env steps  {seconds:6.0f} s training  return train {train:6.1f}  test {test:6.1f}"
                  f"  (last training episode, with exploration noise: {float(st.last_return):.1f})", flush=True)


if __name__ == "__main__":
    main()
