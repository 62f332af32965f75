"""Zero-shot evaluation: jitted, vmapped greedy rollouts over contexts x tasks (x seeds).

For every context, one reward-free episode of the behaviour policy is collected first
(the test-time context for belief agents; context-free agents ignore it), or with
Config.context_episodes = K, K independent ones. Then, by the
environment's `metric`:
    "success" (gridworlds, pointmass): for every goal, the agent infers z from the goal and
        that episode and acts greedily from the evaluation start; score 1 if the goal is
        reached within the episode.
    "return" (antwind): the agent infers z from reward-labelled states of the dataset
        (z = reward_task(states, env.state_reward(states))) and that episode; the score
        is the return of one episode from a reset (one "task" per context).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from zsbfm.agents.base import Context
from zsbfm.data.collect import behaviour_rollout, rollout
from zsbfm.envs.base import index_contexts, num_contexts


def context_episode(env, key, ctx, length: int, episodes: int = 1) -> Context:
    """One reward-free behaviour-policy episode of `length` steps in `ctx` (and `ctx` itself,
    which only the oracle diagnostic reads); episodes > 1: that many independent episodes,
    stacked on a leading axis (obs [episodes, length + 1, obs_dim])."""
    if episodes == 1:
        obs, action, _ = behaviour_rollout(env, key, ctx, length)
    else:
        obs, action, _ = jax.vmap(lambda k: behaviour_rollout(env, k, ctx, length))(
            jax.random.split(key, episodes))
    return Context(obs=obs, action=action, layout=ctx)


def goal_rollout(agent, env, params, key, ctx, context: Context, goal, length: int, start=None):
    """Greedy episode towards `goal` from `start` (default env.eval_start(ctx)).
    Returns (success, obs [T+1, d])."""
    task = agent.goal_task(params, goal, context)
    policy = lambda k, obs: agent.act(params, obs, task, k)
    start = env.eval_start(ctx) if start is None else start
    obs, _, reward = rollout(env, key, ctx, policy, length, goal=goal, start=start)
    return jnp.any(reward > 0), obs


def return_rollout(agent, env, params, key, ctx, context: Context, reward_obs, length: int):
    """The environment's return (control cost included) of one greedy episode, with z
    inferred from env.state_reward on the states reward_obs [n, obs_dim] and h from `context`."""
    task = agent.reward_task(params, reward_obs, env.state_reward(reward_obs), context)
    policy = lambda k, obs: agent.act(params, obs, task, k)
    _, _, reward = rollout(env, key, ctx, policy, length)
    return jnp.sum(reward)


def metric_of(env) -> str:
    """"success" (goal reaching) or "return" (a reward task), by environment."""
    return env.metric


def evaluate_params(agent, env, params, key, contexts, goals, length: int, context_len: int,
                    reward_obs=None, context_episodes: int = 1):
    """Scores of one parameter set (jittable): success bool[n_contexts, n_goals], or for
    metric "return" the returns float32[n_contexts, 1].

    contexts: stacked context pytree [n_contexts, ...]; goals: float32[n_contexts, n_goals,
    obs_dim] (success) or None; reward_obs: float32[n, obs_dim] dataset states for reward
    inference (return); context_episodes: behaviour episodes of context_len steps per test-time
    context (`context_episode`).
    """
    n = num_contexts(contexts)
    if metric_of(env) == "return":
        if reward_obs is None:
            raise ValueError(f"env {env.name!r} scores returns: evaluate_params needs reward_obs")

        def one_return(k, ctx):
            k_ctx, k_roll = jax.random.split(k)
            context = context_episode(env, k_ctx, ctx, context_len, context_episodes)
            return return_rollout(agent, env, params, k_roll, ctx, context, reward_obs, length)[None]

        return jax.vmap(one_return)(jax.random.split(key, n), contexts)
    if goals.shape[0] != n:
        raise ValueError(f"goals must have shape [n_contexts={n}, n_goals, obs_dim], got {goals.shape}")

    def one_context(k, ctx, ctx_goals):
        k_ctx, k_roll = jax.random.split(k)
        context = context_episode(env, k_ctx, ctx, context_len, context_episodes)
        keys = jax.random.split(k_roll, ctx_goals.shape[0])
        success, _ = jax.vmap(lambda kk, g: goal_rollout(agent, env, params, kk, ctx, context, g, length))(
            keys, ctx_goals)
        return success

    return jax.vmap(one_context)(jax.random.split(key, n), contexts, goals)


def protocols_of(env) -> tuple[str, ...]:
    """The evaluation protocols of an environment, the official one first: its
    `eval_protocols` for goal reaching, ("return",) for a reward task."""
    if metric_of(env) == "return":
        return ("return",)
    return tuple(env.eval_protocols)


def evaluate_protocol(agent, env, params, key, contexts, protocol: str, length: int,
                      context_len: int, reward_obs=None, context_episodes: int = 1):
    """Scores of one parameter set under one protocol (jittable): (score float32[n_contexts,
    G], valid bool[n_contexts, G]), the score a success (0/1) or, for "return", the return.

    The tasks (starts, goals, which count) come from env.eval_tasks(ctx, protocol, key);
    the context episode and rollout keys are drawn as in `evaluate_params`, so the
    official protocol gives exactly its scores."""
    if protocol == "return":
        r = evaluate_params(agent, env, params, key, contexts, None, length, context_len, reward_obs,
                            context_episodes)
        return r.astype(jnp.float32), jnp.ones(r.shape, bool)
    n = num_contexts(contexts)

    def one_context(k, ctx):
        k_ctx, k_roll = jax.random.split(k)
        context = context_episode(env, k_ctx, ctx, context_len, context_episodes)
        starts, goals, valid = env.eval_tasks(ctx, protocol, jax.random.fold_in(k, 7))
        keys = jax.random.split(k_roll, goals.shape[0])
        success, _ = jax.vmap(lambda kk, g, st: goal_rollout(agent, env, params, kk, ctx, context, g, length, st))(
            keys, goals, starts)
        return success.astype(jnp.float32), valid

    return jax.vmap(one_context)(jax.random.split(key, n), contexts)


def protocol_score(score, valid):
    """Mean score over the valid tasks of each layout, then over layouts: [..., n_ctx, G] -> [...]."""
    per_layout = jnp.sum(score * valid, -1) / jnp.maximum(jnp.sum(valid, -1), 1)
    return jnp.mean(per_layout, -1)


def default_goals(env, contexts):
    """env.eval_goals of every context: float32[n_contexts, n_goals, obs_dim] (None for
    environments scored by return)."""
    if metric_of(env) == "return":
        return None
    return jax.vmap(env.eval_goals)(contexts)


REWARD_SAMPLES = 10_000  # dataset states z is inferred from (metric "return")


def reward_states(key, dataset, n: int = REWARD_SAMPLES):
    """n states drawn uniformly from the dataset, for reward inference."""
    from zsbfm.data.samplers import sample_states

    return sample_states(key, dataset, n)


def split_results(success) -> dict:
    """Summaries of scores [seeds, n_contexts, n_goals] as plain lists (the "success" key
    holds the mean score per seed: a success rate, or a return for metric "return")."""
    s = jnp.asarray(success, jnp.float32)
    return {"success": s.mean((1, 2)).tolist(), "per_layout": s.mean(2).tolist(),
            "per_goal": s.mean(1).tolist()}


def evaluate(run, contexts=None, goals=None, key=None, split: str = "test", protocol: str | None = None,
             agent=None, context_len: int | None = None, context_episodes: int | None = None):
    """Evaluate every seed of a trained `Run` zero-shot.

    contexts: stacked contexts (default: env.contexts(split)); goals: float32[n_contexts,
    n_goals, obs_dim] (default: the environment's evaluation goals). Returns success
    bool[seeds, n_contexts, n_goals], or returns float32[seeds, n_contexts, 1] for antwind.

    key: None (default) draws each seed's context episodes and rollouts exactly as the
    run's own evaluation did (`zsbfm.keys.eval_key` of the seed's key, then the split's
    key), so with the default contexts and goals this reproduces run.results[split];
    a key draws them afresh from it; a stack of D keys (uint32[D, 2], or typed [D]) draws
    D evaluations in one compiled program, draw i from the same random numbers as
    key=keys[i] alone, and every result gains a leading [D] axis (how much a score owes to
    its draw; memory grows D-fold).
    protocol: None for the goals above; or one of the env's protocols (`protocols_of`:
    "paper", "dense", ...): then returns the (score [seeds, n_contexts, G], valid) pair of
    that protocol on `contexts`, as in run.results["protocols"] (the score is the mean of
    the valid tasks, `protocol_score`).
    agent: None for the run's own agent (`make_agent(run.cfg, env)`); or another agent over
    the same parameters, for a diagnostic (e.g. one whose context_h is told the layout).
    context_len: None for cfg.context_len; or the steps of the test-time context episode (a
    diagnostic: how much context the agent's h needs; the encoder pools any number).
    context_episodes: None for cfg.context_episodes; or the number of such episodes per context.
    """
    from zsbfm.agents import make_agent
    from zsbfm.data.sources import make_env_for
    from zsbfm.keys import eval_key, seed_keys

    cfg = run.cfg
    env = make_env_for(cfg)
    agent = make_agent(cfg, env) if agent is None else agent
    if split not in ("train", "test"):
        raise ValueError(f"split={split!r} is invalid: expected 'train' or 'test'")
    if context_len is None:
        context_len = cfg.context_len
    elif not isinstance(context_len, int) or context_len <= 0:
        raise ValueError(f"context_len={context_len!r} is invalid: expected a positive integer")
    if context_episodes is None:
        context_episodes = cfg.context_episodes
    elif not isinstance(context_episodes, int) or isinstance(context_episodes, bool) or context_episodes <= 0:
        raise ValueError(f"context_episodes={context_episodes!r} is invalid: expected a positive integer")
    if protocol is not None and protocol not in protocols_of(env):  # before the dataset load below
        raise ValueError(f"protocol={protocol!r} is invalid for {cfg.env}: expected one of {protocols_of(env)}")
    contexts = env.contexts(split) if contexts is None else contexts
    seeds = jax.tree_util.tree_leaves(run.params)[0].shape[0]
    if key is None:
        keys = jax.vmap(eval_key)(seed_keys(cfg)[:seeds])                  # [seeds, 2]
    else:
        key = _raw_keys(key)                                              # [2] or [D, 2]
        keys = jnp.reshape(jax.vmap(lambda k: jax.random.split(k, seeds))(key.reshape(-1, 2)),
                           key.shape[:-1] + (seeds, 2))
    # the same split of each seed's key as the training evaluation (train.make_train)
    k_split, k_states = _split_keys(keys, split)
    reward_obs = None
    if metric_of(env) == "return":  # z from the run's (cached) dataset, on the host; goals unused
        from zsbfm.data.sources import shared_dataset

        ds = shared_dataset(cfg, env)
        draw = lambda k: reward_states(k, ds)
        reward_obs = jax.vmap(draw)(k_states) if k_states.ndim == 2 else jax.vmap(jax.vmap(draw))(k_states)
    elif protocol is None:
        goals = default_goals(env, contexts) if goals is None else jnp.asarray(goals, jnp.float32)
        if goals.ndim != 3 or goals.shape[-1] != env.obs_dim:
            raise ValueError(f"goals must be [n_contexts, n_goals, {env.obs_dim}], got shape {goals.shape}")

    def one_seed(params, k, r):
        if protocol is not None:
            return evaluate_protocol(agent, env, params, k, contexts, protocol, cfg.eval_episode_len,
                                     context_len, r, context_episodes)
        return evaluate_params(agent, env, params, k, contexts, goals, cfg.eval_episode_len, context_len, r,
                               context_episodes)

    r_axis = 0 if reward_obs is not None else None
    fn = jax.vmap(one_seed, in_axes=(0, 0, r_axis))
    if k_split.ndim == 3:  # draws [D, seeds, 2]: the same parameters under every draw
        fn = jax.vmap(fn, in_axes=(None, 0, r_axis))
    return jax.jit(fn)(run.params, k_split, reward_obs)


FRESH_DRAW_KEY = 1000  # draw i >= 1 of `score_draws` uses PRNGKey(FRESH_DRAW_KEY + i)


def score_draws(run, draws: int, split: str = "test", protocol: str | None = None, **kwargs):
    """A run's score per seed over `draws` evaluation draws: float32[draws, seeds]. Draw 0 is
    the run's own (what it reported), draws 1.. are fresh context episodes and rollouts from
    PRNGKey(FRESH_DRAW_KEY + i), together in one compiled program (two compiles in all). The
    score is the official one (mean success, or return) or, with a protocol, `protocol_score`.
    kwargs go to `evaluate` (all but key: the draws choose the keys).

    One Four-Rooms evaluation is 60 held-out tasks with one context draw each: a binomial
    standard error of about 0.06 on the success rate, which the mean over draws shrinks.
    """
    if not isinstance(draws, int) or isinstance(draws, bool) or draws <= 0:
        raise ValueError(f"draws={draws!r} is invalid: expected a positive integer")
    if "key" in kwargs:
        raise ValueError("score_draws takes no key: draw 0 is the run's own, draw i PRNGKey(FRESH_DRAW_KEY + i)")

    def score(out):  # [..., seeds, n_contexts, G] -> [..., seeds]
        if protocol is None:
            return jnp.asarray(out, jnp.float32).mean((-2, -1))
        return protocol_score(*out)

    scores = [score(evaluate(run, split=split, protocol=protocol, **kwargs))[None]]
    if draws > 1:
        keys = jnp.stack([jax.random.PRNGKey(FRESH_DRAW_KEY + i) for i in range(1, draws)])
        scores.append(score(evaluate(run, key=keys, split=split, protocol=protocol, **kwargs)))
    return jnp.concatenate(scores)


def standard_error(x, axis: int = 0):
    """The standard error of the mean along `axis`: sample std (ddof 1) / sqrt(n); nan where
    n = 1 (one draw or one seed says nothing of the spread)."""
    x = np.asarray(x)
    n = x.shape[axis]
    if n < 2:
        return np.full(np.mean(x, axis=axis).shape, np.nan)
    return np.std(x, axis=axis, ddof=1) / np.sqrt(n)


def _raw_keys(key):
    """One PRNG key or a stack of them, as raw uint32 [2] or [D, 2] (a typed key's data);
    anything else is a one-line error."""
    if jax.dtypes.issubdtype(getattr(key, "dtype", None), jax.dtypes.prng_key):
        key = jax.random.key_data(key)
    key = jnp.asarray(key)
    if key.dtype != jnp.uint32 or key.ndim not in (1, 2) or key.shape[-1] != 2:
        raise ValueError(f"key of shape {key.shape} and dtype {key.dtype} is invalid: expected one PRNG key "
                         f"(jax.random.PRNGKey) or a stack of them [D, 2]")
    return key


def _split_keys(keys, split: str):
    """Each seed's evaluation key -> (its `split` rollout key, its reward-states key), as
    train.make_train splits it: [..., seeds, 2] -> ([..., seeds, 2], [..., seeds, 2])."""
    three = jax.vmap(lambda k: jax.random.split(k, 3))(keys.reshape(-1, 2))       # [n, 3, 2]
    k_train, k_test, k_states = (three[:, i].reshape(keys.shape) for i in range(3))
    return (k_train if split == "train" else k_test), k_states
