import os

os.environ.setdefault("JAX_PLATFORMS", "cpu")

import pytest  # noqa: E402

import zsbfm  # noqa: E402


def tiny_config(tmp_path, algo="fb", env="fourrooms", **overrides):
    """A config of `algo` on `env` (FB on fourrooms by default) small enough for a test (seconds)."""
    base = dict(num_seeds=2, n_train_layouts=4, episodes_per_layout=20, d=8,
                f_pre_hidden=(16,), f_pre_out=16, f_hidden=(32,), b_hidden=(16,), batch_size=32,
                steps=40, chunk_steps=10, eval_episode_len=20, context_len=20,
                runs_dir=str(tmp_path / "runs"), name="tiny")
    base.update(overrides)
    return zsbfm.Config.preset(env, algo, **base)


@pytest.fixture
def tiny_cfg(tmp_path):
    return tiny_config(tmp_path)
