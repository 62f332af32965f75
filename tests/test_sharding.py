"""The seed axis sharded over devices (forced host devices, in subprocesses)."""

import json
import subprocess
import sys

import numpy as np
import pytest

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

    with pytest.raises(ValueError, match="num_seeds=3 .*multiple of the 2 local devices"):
        seed_sharding(3, jax.local_devices() * 2)
