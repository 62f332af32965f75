"""A tiny data-parallel run on 2 forced host devices, for tests/test_sharding.py.

    python tests/helpers/data_parallel_run.py RUNS_DIR

Trains the tiny 2-seed config with data_parallel=2 (mesh 1 seed row x 2 data devices)
through zsbfm.train into RUNS_DIR/runs/dp (its checkpoints are resumed by the test on one
device), with XLA dumping the chunk module it compiled, and reports that module's
cross-device all-reduces and whether its per-device batch arrays are half batches. With
the "data" axis ignored, every device would run the whole replicated program: whole
batches and no all-reduce (as the seed-only 2 x 1 mesh's chunk has: 0 all-reduces, no
half batch, checked when this was written). Prints one JSON line.
"""
import json
import os
import pathlib
import re
import sys

os.environ["XLA_FLAGS"] = (f"--xla_force_host_platform_device_count=2 --xla_dump_to={sys.argv[1]}/hlo "
                           "--xla_dump_hlo_module_re=run_chunk --xla_dump_hlo_as_text")
os.environ["JAX_PLATFORMS"] = "cpu"
sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

import jax  # noqa: E402

import zsbfm  # noqa: E402
from conftest import tiny_config  # noqa: E402

runs = pathlib.Path(sys.argv[1])
cfg = tiny_config(runs, data_parallel=2, steps=30, chunk_steps=10, name="dp")  # runs in RUNS_DIR/runs
out = {"devices": jax.device_count()}

run = zsbfm.train(cfg, progress=False)
out["train"] = run.results["train"]

# the chunk zsbfm.train compiled (XLA's dump of the optimised, partitioned module):
hlo = "".join(p.read_text() for p in (runs / "hlo").glob("*run_chunk*after_optimizations.txt"))
out["chunk_modules"] = len(list((runs / "hlo").glob("*run_chunk*after_optimizations.txt")))
# the batch's sampled transition indices per device: s32[seeds per device, batch per device]
# (half batches present, whole batches absent)
out["all_reduce"] = len(re.findall(r"\ball-reduce(?:-start)?\(", hlo))
out["half_batch"] = (bool(re.search(rf"s32\[\d+,{cfg.batch_size // 2}\]", hlo))
                     and not re.search(rf"s32\[\d+,{cfg.batch_size}\]", hlo))
print(json.dumps(out))
