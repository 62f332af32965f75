"""Reference returns on AntWind: the wind-aware expert behind the data, and random actions.

    python experiments/antwind_expert.py [--episodes 4] [--set expert_steps=1000000 ...]

Uses the CPU preset's cached expert (trained first if missing, like `make data
ENV=antwind`); `--set` overrides Config fields (another expert is trained and cached
under its own digest). For every train and test wind, `--episodes` 256-step episodes of: the
expert without noise, the expert with the data's noise (the behaviour policy), and
uniformly random actions. The expert *sees the wind* (it is an upper reference, not a
zero-shot method). Writes results/antwind_expert.json.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os

import jax
import numpy as np

from zsbfm.config import Config
from zsbfm.data.collect import behaviour_returns
from zsbfm.data.sources import make_env_for


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--episodes", type=int, default=4)
    p.add_argument("--out", default="results/antwind_expert.json")
    p.add_argument("--set", nargs="*", default=[], help="Config overrides (field=value), e.g. expert_steps=1000000")
    a = p.parse_args()
    cfg = Config.preset("antwind").with_overrides(a.set)
    env = make_env_for(cfg)
    policies = {"expert (no noise)": dataclasses.replace(env, behaviour=dataclasses.replace(env.behaviour, noise=0.0)),
                f"expert + noise {cfg.expert_noise} (behaviour)": env,
                "random actions": dataclasses.replace(env, behaviour=None)}
    out = {}
    for name, e in policies.items():
        row = {}
        for split in ("train", "test"):
            returns = jax.jit(lambda key, ctxs, e=e: behaviour_returns(e, key, ctxs, a.episodes))
            ret = returns(jax.random.PRNGKey(3), e.contexts(split))   # [winds, episodes]
            row[split] = {"mean": float(np.mean(ret)), "std_over_winds": float(np.std(np.mean(ret, 1)))}
        out[name] = row
        print(f"{name:28s} train {row['train']['mean']:7.1f}  test {row['test']['mean']:7.1f}", flush=True)
    os.makedirs(os.path.dirname(a.out) or ".", exist_ok=True)
    with open(a.out, "w") as f:
        json.dump(out, f, indent=2)


if __name__ == "__main__":
    main()
