"""Runs saved by an earlier version still load and evaluate to the numbers they reported."""

import json
import os

import numpy as np
import pytest

import zsbfm
from zsbfm.evaluate import protocol_score

# A tiny 2-seed FB run on Four-Rooms (400 updates) written at commit c971d54, the last with
# the removed options (zsbfm.config.REMOVED_FIELDS): its config.json still holds h_cond,
# twin_target (since returned as a field), lr_schedule and enc_pred_horizon, at the values
# that remain.
FIXTURE = os.path.join(os.path.dirname(__file__), "fixtures", "fb_c971d54")


def test_a_run_saved_before_the_options_were_removed_evaluates_to_its_numbers():
    with open(os.path.join(FIXTURE, "config.json")) as f:
        assert {"h_cond", "twin_target", "lr_schedule", "enc_pred_horizon"} <= set(json.load(f))
    run = zsbfm.load(FIXTURE)
    assert run.cfg.steps == 400 and run.cfg.num_seeds == 2
    for protocol in ("dense", "random_start"):
        reported = run.results["protocols"][protocol]
        assert max(max(v) for v in reported.values()) > 0  # numbers that could differ
        for split in ("train", "test"):
            again = np.asarray(protocol_score(*zsbfm.evaluate(run, split=split, protocol=protocol)))
            np.testing.assert_allclose(again, reported[split], atol=1e-4)


@pytest.mark.parametrize("field,value", [("h_cond", "film"), ("lr_schedule", "cosine"), ("enc_pred_horizon", 3),
                                         ("obs_encoding", "cell")])
def test_a_run_that_used_a_removed_option_is_a_one_line_error(field, value):
    with open(os.path.join(FIXTURE, "config.json")) as f:
        d = json.load(f)
    d[field] = value
    with pytest.raises(ValueError, match=rf"Config.{field}={value!r} is a removed option .* c971d54 or earlier"):
        zsbfm.Config.from_dict(d)


def test_setting_a_removed_field_names_it():
    with pytest.raises(ValueError, match="Config.h_cond='film' is a removed option"):
        zsbfm.Config.preset("fourrooms", "bfb", h_cond="film")
    with pytest.raises(ValueError, match="Config.lr_schedule='cosine' is a removed option"):
        zsbfm.Config.preset("fourrooms").with_overrides(["lr_schedule=cosine"])


def test_evaluate_takes_another_agent_over_the_same_parameters():
    """evaluate(run, agent=...): the run's own agent gives its numbers; an agent that sets
    every goal's z to B of the start cell (a diagnostic's variant) gives others."""
    import dataclasses

    import jax.numpy as jnp

    from zsbfm.agents import make_agent
    from zsbfm.agents.base import Task
    from zsbfm.data.sources import make_env_for

    run = zsbfm.load(FIXTURE)
    env = make_env_for(run.cfg, progress=False)
    own = make_agent(run.cfg, env)

    class StartGoal(type(own)):
        def goal_task(self, params, goal_obs, context):
            return Task(z=self.backward(params.B, jnp.ones_like(goal_obs)), h=self.context_h(params, context))

    other = StartGoal(**{f.name: getattr(own, f.name) for f in dataclasses.fields(own)})
    reported = run.results["protocols"]["dense"]["train"]
    score = lambda agent: np.asarray(protocol_score(*zsbfm.evaluate(run, split="train", protocol="dense", agent=agent)))
    np.testing.assert_allclose(score(own), reported, atol=1e-4)
    assert not np.allclose(score(other), reported, atol=1e-2)


def test_evaluate_rejects_a_bad_context_len():
    with pytest.raises(ValueError, match="context_len=0"):
        zsbfm.evaluate(zsbfm.load(FIXTURE), context_len=0)


def test_evaluate_rejects_a_bad_context_episodes():
    with pytest.raises(ValueError, match="context_episodes=0"):
        zsbfm.evaluate(zsbfm.load(FIXTURE), context_episodes=0)


def test_evaluate_over_a_stack_of_keys_is_each_key_alone_in_one_program():
    """key=[D] keys: one compiled program whose draw i is evaluate(key=keys[i]), scores and
    validity alike; the draws differ from each other (fresh contexts and rollouts)."""
    import jax
    import jax.numpy as jnp

    run = zsbfm.load(FIXTURE)
    keys = jnp.stack([jax.random.PRNGKey(5), jax.random.PRNGKey(6)])
    score, valid = zsbfm.evaluate(run, split="test", protocol="random_start", key=keys)
    assert score.shape[:2] == (2, run.cfg.num_seeds)
    for i in range(2):
        one_score, one_valid = zsbfm.evaluate(run, split="test", protocol="random_start", key=keys[i])
        np.testing.assert_array_equal(np.asarray(score[i]), np.asarray(one_score))
        np.testing.assert_array_equal(np.asarray(valid[i]), np.asarray(one_valid))
    assert not np.array_equal(np.asarray(score[0]), np.asarray(score[1]))
    success = zsbfm.evaluate(run, split="train", key=keys)  # the default goals, too
    assert success.shape[:2] == (2, run.cfg.num_seeds) and success.dtype == bool


@pytest.mark.parametrize("key", [np.zeros((2, 3, 2), np.uint32), np.zeros((3,), np.uint32)])
def test_evaluate_rejects_a_key_of_another_shape(key):
    with pytest.raises(ValueError, match=r"key of shape \("):
        zsbfm.evaluate(zsbfm.load(FIXTURE), key=key)


def test_score_draws_rejects_a_bad_number_of_draws():
    from zsbfm.evaluate import score_draws

    with pytest.raises(ValueError, match="draws=0"):
        score_draws(zsbfm.load(FIXTURE), 0)


def test_typed_keys_are_read_as_their_raw_data():
    import jax

    from zsbfm.evaluate import _raw_keys

    np.testing.assert_array_equal(np.asarray(_raw_keys(jax.random.key(3))), np.asarray(jax.random.PRNGKey(3)))
    stack = jax.random.split(jax.random.key(3), 4)
    assert _raw_keys(stack).shape == (4, 2)


def test_evaluate_rejects_an_unknown_protocol():
    with pytest.raises(ValueError, match="protocol='nope' is invalid for fourrooms"):
        zsbfm.evaluate(zsbfm.load(FIXTURE), protocol="nope")


def test_standard_error_is_the_sample_std_over_root_n():
    from zsbfm.evaluate import standard_error
    # [1, 2, 3, 4]: sample variance 5/3, so se = sqrt(5/3) / 2
    np.testing.assert_allclose(standard_error([1.0, 2.0, 3.0, 4.0]), np.sqrt(5 / 3) / 2)
    np.testing.assert_allclose(standard_error(np.array([[1.0, 0.0], [3.0, 0.0]])), [1.0, 0.0])  # per column
    assert np.isnan(standard_error([0.3])) and standard_error(np.ones((1, 3))).shape == (3,)
