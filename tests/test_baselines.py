"""Baselines against exact quantities (BFS distances, orthonormality) and end to end."""

import json
from collections import deque

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import zsbfm
from zsbfm.agents import HILPAgent, LaplacianAgent, Task, make_agent
from zsbfm.agents.sf import lstsq_z
from zsbfm.data import collect
from zsbfm.envs import GridContext
from zsbfm.envs.gridworld import ACTION_DELTAS
from tests.conftest import jit_optimised, tiny_config


def corridor_room():
    """A 4x4 open room with a wall stub (cells x, y in 1..4) inside the fourrooms frame."""
    env = zsbfm.make_env("fourrooms", n_train=1, episode_len=50)
    walls = np.ones((11, 11), bool)
    walls[1:5, 1:5] = False
    walls[2, 1:4] = True  # row y=2 blocked for x=1..3: a U-shaped room, distances != Manhattan
    cells = [(x, y) for y in range(1, 5) for x in range(1, 5) if not walls[y, x]]
    return env, GridContext(walls=jnp.asarray(walls)[None]), cells, walls


def bfs_distances(walls, cells):
    idx = {c: i for i, c in enumerate(cells)}
    D = np.full((len(cells), len(cells)), np.inf)
    for s, c in enumerate(cells):
        D[s, s] = 0
        q = deque([c])
        while q:
            x, y = q.popleft()
            for dx, dy in ACTION_DELTAS:
                n = (x + dx, y + dy)
                if n in idx and D[s, idx[n]] == np.inf:
                    D[s, idx[n]] = D[s, idx[(x, y)]] + 1
                    q.append(n)
    return D


def train_agent(agent, ds, steps, seed=1):
    state = jax.jit(agent.init)(jax.random.PRNGKey(seed))
    run = jit_optimised(lambda s, k: jax.lax.scan(lambda s, k: agent.update(s, ds, k), s, jax.random.split(k, steps)))
    state, metrics = run(state, jax.random.PRNGKey(seed + 1))
    return state, metrics


def small_cfg(algo, **kw):
    base = dict(d=8, f_pre_hidden=(32,), f_pre_out=32, f_hidden=(64,), feat_hidden=(64, 64),
                batch_size=128, lr=1e-3)
    base.update(kw)
    return zsbfm.Config.preset("fourrooms", algo, **base)


@pytest.mark.slow  # a learning-quality check (~20-40 s): make test-all
def test_hilp_value_orders_states_by_bfs_distance():
    env, ctxs, cells, walls = corridor_room()
    ds = collect(env, jax.random.PRNGKey(0), ctxs, 200)
    agent = HILPAgent(small_cfg("hilp", feat_tau=0.05, hilp_expectile=0.9), env)
    state, m = train_agent(agent, ds, 1500)
    assert np.isfinite(np.asarray(m["phi_loss"])).all()
    phi = np.asarray(agent.phi(state.params.B, jnp.asarray(cells, jnp.float32)))
    V = -np.linalg.norm(phi[:, None] - phi[None], axis=-1)          # V[s, g]
    D = bfs_distances(walls, cells)
    agree = total = 0
    for g in range(len(cells)):
        for a in range(len(cells)):
            for b in range(len(cells)):
                if D[a, g] < D[b, g]:
                    total += 1
                    agree += V[a, g] > V[b, g]
    assert agree / total > 0.85, f"value ordering agrees with BFS on {agree / total:.2f} of pairs"


@pytest.mark.slow  # a learning-quality check (~20-40 s): make test-all
def test_laplacian_features_become_orthonormal():
    """With phi = sqrt(c) f for an orthonormal f of Dirichlet energy lam, the loss
    c lam + coef (c^2 - 2c) is minimal at c = 1 - lam / (2 coef): the smoothness term
    shrinks the Gram matrix by lam / (2 coef) <= 2 / coef (lam <= 4 on unit steps),
    so a large ortho_coef must bring it within a few hundredths of I."""
    env, ctxs, cells, _ = corridor_room()
    ds = collect(env, jax.random.PRNGKey(0), ctxs, 200)
    agent = LaplacianAgent(small_cfg("lap", d=4, ortho_coef=20.0), env)
    phi0 = np.asarray(agent.phi(agent.init(jax.random.PRNGKey(1)).params.B, ds.obs[:, 1:].reshape(-1, 2)))
    state, _ = train_agent(agent, ds, 1500)
    states = ds.obs[:, 1:].reshape(-1, 2)                    # the data distribution rho
    phi = np.asarray(agent.phi(state.params.B, states))
    gram = phi.T @ phi / len(phi)
    gram0 = phi0.T @ phi0 / len(phi0)
    err, err0 = np.abs(gram - np.eye(4)).max(), np.abs(gram0 - np.eye(4)).max()
    assert err < 0.12, f"Phi^T Phi / n deviates from I by {err:.3f} (init {err0:.3f})"
    assert err < err0


def test_least_squares_z_recovers_linear_reward():
    phi = jax.random.normal(jax.random.PRNGKey(0), (500, 6))
    z_true = jnp.arange(1.0, 7.0)
    np.testing.assert_allclose(lstsq_z(phi, phi @ z_true), z_true, rtol=1e-3)


def test_hilp_goal_z_is_recomputed_from_the_current_state():
    env, ctxs, cells, _ = corridor_room()
    agent = HILPAgent(small_cfg("hilp"), env)
    params = agent.init(jax.random.PRNGKey(0)).params
    goal = jnp.asarray([4.0, 4.0])
    task = agent.goal_task(params, goal, None)
    for s in (jnp.asarray([1.0, 1.0]), jnp.asarray([3.0, 4.0])):
        z = jnp.sqrt(8.0) * (task.goal - agent.phi(params.B, s)) / jnp.linalg.norm(task.goal - agent.phi(params.B, s))
        expect = jnp.argmax(agent.q_values(params, s, Task(z=z, h=task.h)))
        assert int(agent.act(params, s, task, jax.random.PRNGKey(0))) == int(expect)


def test_oracle_sees_the_true_layout_and_nothing_on_test_layouts():
    cfg = zsbfm.Config.preset("fourrooms", "oracle", n_train_layouts=5)
    env = zsbfm.make_env("fourrooms", n_train=5)
    agent = make_agent(cfg, env)
    params = agent.init(jax.random.PRNGKey(0)).params
    from zsbfm.evaluate import context_episode
    from zsbfm.envs.base import index_contexts
    for split, expect in (("train", np.eye(5)[3]), ("test", np.zeros(5))):
        ctx = index_contexts(env.contexts(split), 3)
        context = context_episode(env, jax.random.PRNGKey(1), ctx, 10)
        np.testing.assert_array_equal(agent.context_h(params, context), expect)


# random, lap: the harness test; hilp trains, saves and loads in test_sweep (evaluate_reproduces)
@pytest.mark.parametrize("algo", [pytest.param(a, marks=pytest.mark.slow) for a in ("oracle", "hilp")])
def test_every_algo_trains_and_evaluates(tmp_path, algo):
    cfg = tiny_config(tmp_path, algo, feat_hidden=(16,), name=f"tiny-{algo}")
    run = zsbfm.train(cfg, progress=False)
    for split in ("train", "test"):
        assert len(run.results[split]) == cfg.num_seeds
        assert all(0.0 <= v <= 1.0 for v in run.results[split])
    loaded = zsbfm.load(f"{cfg.runs_dir}/{cfg.run_name}")
    assert loaded.results == run.results


@pytest.mark.slow  # experiments/table.py over four tiny runs, ~27 s: `make test-all`
def test_table_harness_writes_results_and_reads_finished_runs_back(tmp_path, capsys):
    import sys

    sys.path.insert(0, "experiments")
    import table

    tiny = ["n_train_layouts=4", "episodes_per_layout=20", "d=8", "f_pre_hidden=16", "f_pre_out=16",
            "f_hidden=32", "b_hidden=16", "feat_hidden=16", "batch_size=32", "steps=20", "chunk_steps=10",
            "eval_episode_len=20", "context_len=20"]
    runs = str(tmp_path / "runs")
    rows = table.run_table("fourrooms", ["random", "lap"], 2, runs, tiny)
    assert set(rows) == {"random", "lap"} and all(len(r["test"]) == 2 for r in rows.values())
    again = table.run_table("fourrooms", ["random", "lap"], 2, runs, tiny)
    assert "read back" in capsys.readouterr().out
    strip = lambda rs: {a: {k: v for k, v in r.items() if k != "measured"} for a, r in rs.items()}
    assert strip(again) == strip(rows)
    assert all(r["measured"].endswith("(read back)") for r in again.values())
    md = table.markdown("fourrooms", rows, 2, "cpu", "success")
    assert "| Laplacian |" in md and "0.20 / 0.10" in md  # the paper's LAP values beside ours
    table.bar_chart("fourrooms", rows, str(tmp_path / "fourrooms.png"), "success")
    assert (tmp_path / "fourrooms.png").stat().st_size > 0


def test_table_keeps_overridden_and_stale_runs_apart(tmp_path):
    import dataclasses
    import sys

    sys.path.insert(0, "experiments")
    import table

    runs = str(tmp_path)
    plain = table.sweep_config("fourrooms", "fb", "cpu", 3, runs, [])
    short = table.sweep_config("fourrooms", "fb", "cpu", 3, runs, ["steps=2000"])
    assert plain.run_name == "fourrooms-fb-cpu" and short.run_name.startswith("fourrooms-fb-cpu-")
    assert short.run_name == table.sweep_config("fourrooms", "fb", "cpu", 3, runs, ["steps=2000"]).run_name
    old_dir = tmp_path / plain.run_name
    old_dir.mkdir()
    (old_dir / "config.json").write_text(dataclasses.replace(plain, lr=0.5).to_json())
    table.set_aside_stale(plain)  # another config: moved aside, not deleted
    assert not old_dir.exists() and (tmp_path / f"{plain.run_name}.stale-1" / "config.json").exists()
    old_dir.mkdir()
    (old_dir / "config.json").write_text(dataclasses.replace(plain, runs_dir="elsewhere").to_json())
    table.set_aside_stale(plain)  # the same run stored elsewhere: kept
    assert old_dir.exists()


def test_table_merges_a_partial_table_into_the_same_header_only(tmp_path):
    import sys

    sys.path.insert(0, "experiments")
    import table

    path = str(tmp_path / "fourrooms.json")
    header = {"env": "fourrooms", "seeds": 3, "size": "cpu", "overrides": []}
    row = lambda v: {"train": [v], "test": [v], "measured": f"day {v}"}
    with open(path, "w") as f:
        json.dump({**header, "methods": {"fb": row(0.1), "bfb": row(0.2)}}, f)
    merged = table.merge_rows(path, header, {"rfb": row(0.3), "bfb": row(0.4)})
    # the rerun method replaces its row, the others stay as measured, in the table's order
    assert list(merged) == ["fb", "bfb", "rfb"]
    assert merged["fb"] == row(0.1) and merged["bfb"] == row(0.4)
    other = dict(header, overrides=["batch_size=512"])  # another preset's table: not merged
    assert list(table.merge_rows(path, other, {"rfb": row(0.3)})) == ["rfb"]
    # a row that records its config is kept only while it is today's config of its method
    today = lambda algo: table.sweep_config("fourrooms", algo, "cpu", 3, "runs", [])
    with open(path, "w") as f:
        json.dump({**header, "methods": {"fb": {**row(0.1), "config": table.comparable(today("fb"))},
                                         "bfb": {**row(0.2), "config": table.comparable(today("fb"))}}}, f)
    assert list(table.merge_rows(path, header, {"rfb": row(0.3)}, today)) == ["fb", "rfb"]
    # a field added to Config since the row was measured: kept at its default, dropped off it
    recorded = {k: v for k, v in table.comparable(today("bfb")).items() if k != "h_from"}
    assert table.same_config(recorded, today("bfb"))
    assert not table.same_config(recorded, today("bfb").replace(h_from="context"))
