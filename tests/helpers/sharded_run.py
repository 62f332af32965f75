"""Run a tiny 4-seed training on N forced host devices and print per-seed results as JSON.

    python tests/helpers/sharded_run.py DEVICES RUNS_DIR [STOP_AFTER_CHUNKS]

Used by tests/test_sharding.py in subprocesses (the device count is fixed at JAX start-up).
STOP_AFTER_CHUNKS > 0 kills the run after that many chunks (to test resuming elsewhere).
"""
import json
import os
import sys

os.environ["XLA_FLAGS"] = f"--xla_force_host_platform_device_count={sys.argv[1]}"
os.environ["JAX_PLATFORMS"] = "cpu"

import jax  # noqa: E402
import numpy as np  # noqa: E402

import zsbfm  # noqa: E402

cfg = zsbfm.Config.preset("fourrooms", "fb", num_seeds=4, n_train_layouts=4, episodes_per_layout=20, d=8,
                          f_pre_hidden=(16,), f_pre_out=16, f_hidden=(32,), b_hidden=(16,), batch_size=32,
                          steps=40, chunk_steps=10, eval_episode_len=20, context_len=20,
                          runs_dir=sys.argv[2], name="shard")
stop = int(sys.argv[3]) if len(sys.argv) > 3 else 0


def kill(chunk, row):
    if stop and chunk == stop:
        raise KeyboardInterrupt


try:
    run = zsbfm.train(cfg, progress=False, callback=kill)
except KeyboardInterrupt:
    print(json.dumps({"stopped": stop}))
    sys.exit(0)
print(json.dumps({"devices": jax.device_count(),
                  "params": [np.asarray(x).reshape(4, -1).tolist() for x in jax.tree_util.tree_leaves(run.params)][:3],
                  "train": run.results["train"], "resumed_from_chunk": run.results["resumed_from_chunk"]}))
