"""One process of a multi-process tiny run (jax.distributed on localhost, CPU, gloo).

    python tests/helpers/multiprocess_run.py PROCESS_ID NUM_PROCESSES PORT RUNS_DIR DATA_PARALLEL

Started NUM_PROCESSES times by tests/test_sharding.py. Initialises the distributed
runtime the way `python -m zsbfm train --coordinator ...` does (zsbfm.cli.init_distributed),
trains the tiny 2-seed config on the global mesh of all processes' devices (one CPU
device each) and prints one JSON line: this process's view of the finished run.
"""
import hashlib
import json
import os
import pathlib
import sys

os.environ["JAX_PLATFORMS"] = "cpu"
os.environ.pop("XLA_FLAGS", None)  # one CPU device per process
sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from zsbfm.cli import init_distributed  # noqa: E402

pid, nproc, port, runs, dp = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3], pathlib.Path(sys.argv[4]), int(sys.argv[5])
assert init_distributed(f"localhost:{port}", nproc, pid)  # before anything touches a device

import jax  # noqa: E402
import numpy as np  # noqa: E402

import zsbfm  # noqa: E402
from conftest import tiny_config  # noqa: E402

cfg = tiny_config(runs, data_parallel=dp, steps=30, chunk_steps=10, name="mp")
run = zsbfm.train(cfg, progress=False)
leaves = [np.asarray(x) for x in jax.tree_util.tree_leaves(run.params)]  # replicated on every process
print(json.dumps({"process": jax.process_index(), "processes": jax.process_count(),
                  "devices": jax.device_count(), "local_devices": jax.local_device_count(),
                  "params_sha": hashlib.sha256(b"".join(x.tobytes() for x in leaves)).hexdigest(),
                  "params_sum": [float(np.abs(x).sum()) for x in leaves],
                  "train": run.results["train"]}))
