"""The seed axis sharded over devices (forced host devices, in subprocesses)."""

import json
import pathlib
import shutil
import socket
import subprocess
import sys

import jax
import numpy as np
import pytest

import zsbfm
from conftest import tiny_config
from zsbfm.train import seed_sharding


def sharded_run(devices: int, runs_dir, stop: int = 0) -> dict:
    out = subprocess.run([sys.executable, "tests/helpers/sharded_run.py", str(devices), str(runs_dir), str(stop)],
                         capture_output=True, text=True, check=True, timeout=600)
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.slow  # four subprocesses, ~90 s: `make test-all`
def test_four_devices_give_the_single_device_run_and_resume_on_one(tmp_path):
    one = sharded_run(1, tmp_path / "one")
    four = sharded_run(4, tmp_path / "four")
    assert one["devices"] == 1 and four["devices"] == 4
    for a, b in zip(one["params"], four["params"]):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), atol=1e-5)
    # killed after 2 chunks on 4 devices, resumed on 1: the same run
    assert sharded_run(4, tmp_path / "moved", stop=2) == {"stopped": 2}
    resumed = sharded_run(1, tmp_path / "moved")
    # the process exits right after the kill, so chunk 2's asynchronous save may be lost
    # (as with a real kill): it resumes from the newest checkpoint that was committed
    assert resumed["resumed_from_chunk"] in (1, 2)
    for a, b in zip(one["params"], resumed["params"]):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), atol=1e-5)


def test_seeds_not_divisible_by_devices_is_a_clear_error():
    import jax

    with pytest.raises(ValueError, match="num_seeds=3 .*multiple of the 2 devices of the .seeds. mesh axis"):
        seed_sharding(3, jax.local_devices() * 2)


# --- data-parallel batch and multi-process runs (issue 7, items 2-3) -----------------------

def _tree_close(a, b, rtol=1e-5, atol=1e-6):
    la, lb = jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b)
    assert len(la) == len(lb)
    for x, y in zip(la, lb):
        np.testing.assert_allclose(np.asarray(x), np.asarray(y), rtol=rtol, atol=atol)


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """The tiny 2-seed, 3-chunk run on this process's one device (data_parallel=1)."""
    assert jax.device_count() == 1
    tmp = tmp_path_factory.mktemp("reference")
    return zsbfm.train(tiny_config(tmp, steps=30, chunk_steps=10, name="ref"), progress=False)


@pytest.mark.slow  # a 2-device subprocess, ~50 s: `make test-all` (the default run keeps the 1-device mesh)
def test_data_parallel_equals_single_device_and_resumes_on_one(tmp_path, reference):
    out = subprocess.run([sys.executable, "tests/helpers/data_parallel_run.py", str(tmp_path)],
                         capture_output=True, text=True, check=True, timeout=300)
    out = json.loads(out.stdout.strip().splitlines()[-1])
    assert out["devices"] == 2
    # the batch really is split: half a batch per device, and the gradient all-reduced
    assert out["chunk_modules"] == 1 and out["half_batch"] and out["all_reduce"] > 0
    # data_parallel=2 on 2 devices == 1 device, same global batches (params written by 2
    # devices, read back on 1)
    run_dir = tmp_path / "runs" / "dp"
    _tree_close(zsbfm.load(str(run_dir)).params, reference.params)
    assert out["train"] == reference.results["train"]
    # as if killed after chunk 2 on 2 devices: resume on 1 device with data_parallel=1
    shutil.rmtree(run_dir / "checkpoints" / "3")
    resumed = zsbfm.train(tiny_config(tmp_path, steps=30, chunk_steps=10, name="dp"), progress=False)
    assert resumed.results["resumed_from_chunk"] == 2
    _tree_close(resumed.params, reference.params)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("localhost", 0))
        return s.getsockname()[1]


def multiprocess_run(tmp_path, data_parallel: int, n: int = 2) -> list[dict]:
    port = _free_port()
    procs = [subprocess.Popen([sys.executable, "tests/helpers/multiprocess_run.py", str(i), str(n), str(port),
                               str(tmp_path), str(data_parallel)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True) for i in range(n)]
    outs = []
    try:
        for p in procs:
            stdout, stderr = p.communicate(timeout=300)
            assert p.returncode == 0, stderr[-3000:]
            outs.append(json.loads(stdout.strip().splitlines()[-1]))
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
    return outs


# Both slow (two processes compiling at once, ~90 s on 2 cores): `make test-all`. The default
# run keeps the single-process data-parallel test above.
@pytest.mark.slow
@pytest.mark.parametrize("data_parallel", [1, 2])
def test_two_processes_train_together_like_one(tmp_path, reference, data_parallel):
    """Two processes (jax.distributed on localhost, gloo), one CPU device each: the seeds
    (data_parallel=1) or each seed's batch (data_parallel=2) split across the processes."""
    outs = multiprocess_run(tmp_path, data_parallel)
    assert [o["process"] for o in outs] == [0, 1]
    assert all(o["processes"] == 2 and o["devices"] == 2 and o["local_devices"] == 1 for o in outs)
    assert outs[0]["params_sha"] == outs[1]["params_sha"]  # both hold the same finished run
    assert outs[0]["train"] == reference.results["train"]
    saved = zsbfm.load(str(tmp_path / "runs" / "mp"))  # written once, read back on one device
    _tree_close(saved.params, reference.params)
    np.testing.assert_allclose(outs[0]["params_sum"],
                               [float(np.abs(np.asarray(x)).sum()) for x in jax.tree_util.tree_leaves(saved.params)],
                               rtol=1e-6)


def test_data_parallel_errors_name_the_value():
    import jax

    with pytest.raises(ValueError, match="data_parallel=3 .*divisor of batch_size=32"):
        tiny_config(pathlib.Path("/tmp"), data_parallel=3)
    with pytest.raises(ValueError, match="data_parallel=0 .*positive integer"):
        tiny_config(pathlib.Path("/tmp"), data_parallel=0)
    with pytest.raises(ValueError, match="data_parallel=4 .*divisor of the 2 devices"):
        seed_sharding(2, jax.local_devices() * 2, data_parallel=4)
    with pytest.raises(ValueError, match="num_seeds=3 .*multiple of the 2 devices .*data_parallel=2"):
        seed_sharding(3, jax.local_devices() * 4, data_parallel=2)
    from zsbfm.cli import init_distributed

    with pytest.raises(ValueError, match="--process-id"):
        init_distributed("localhost:1234", 2, 5)
    assert not init_distributed("", 0, -1)  # no coordinator, one process: nothing to start
