"""The AntWind TD3 expert's learning curve: train it (zsbfm.data.expert.train_expert, not
cached) and every `--every` env steps score the noise-free policy on the train and held-out
winds (4 episodes per wind, the keys of experiments/antwind_expert.py), with the training
time so far.

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
from zsbfm.data.expert import ExpertBehaviour, ExpertSettings, save_expert_npz, train_expert


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

    @jax.jit
    def returns(params):
        """Mean noise-free return on the train and the test winds (antwind_expert.py's keys)."""
        e = dataclasses.replace(env, behaviour=ExpertBehaviour(env, s, 0.0, params))
        return [behaviour_returns(e, jax.random.PRNGKey(3), e.contexts(split), 4).mean() for split in ("train", "test")]

    per_chunk, clock = s.chunk * s.num_envs, {"training": 0.0, "since": time.perf_counter()}

    def point(done, st):
        """After each chunk (train_expert's callback): score, save and print at every --every."""
        clock["training"] += time.perf_counter() - clock["since"]  # the chunk, its sync included
        if done // a.every != (done - per_chunk) // a.every or done == s.iters * s.num_envs:
            train, test = (float(r) for r in returns(st.actor))
            if a.save:
                os.makedirs(a.save, exist_ok=True)
                save_expert_npz(os.path.join(a.save, f"actor-{done}.npz"), st.actor)
            print(f"{done:>9,} env steps  {clock['training']:6.0f} s training  return train {train:6.1f}  "
                  f"test {test:6.1f}  (last training episode, with exploration noise: "
                  f"{float(st.last_return):.1f})", flush=True)
        clock["since"] = time.perf_counter()

    print(f"ExpertSettings overrides {over}")
    train_expert(env, s, progress=False, callback=point)

if __name__ == "__main__":
    main()
