"""Gridworld mechanics checked against an independent BFS over the wall arrays."""

from collections import deque

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import zsbfm
from zsbfm.envs import index_contexts

DELTAS = {0: (0, -1), 1: (0, 1), 2: (-1, 0), 3: (1, 0)}


def bfs(walls, start):
    """Distances (dict (x, y) -> steps) from start over free cells, 4-connected."""
    h, w = walls.shape
    dist, q = {start: 0}, deque([start])
    while q:
        x, y = q.popleft()
        for dx, dy in DELTAS.values():
            nx, ny = x + dx, y + dy
            if 0 <= nx < w and 0 <= ny < h and not walls[ny, nx] and (nx, ny) not in dist:
                dist[(nx, ny)] = dist[(x, y)] + 1
                q.append((nx, ny))
    return dist


def free_cells(walls):
    ys, xs = np.nonzero(~walls)
    return set(zip(xs.tolist(), ys.tolist()))


def all_layouts(name, n_train):
    env = zsbfm.make_env(name, n_train=n_train)
    return env, np.asarray(env.contexts("train").walls), np.asarray(env.contexts("test").walls)


@pytest.mark.parametrize("name,n_train", [("doors", 29), ("fourrooms", 50)])
def test_every_free_cell_reachable_and_border_closed(name, n_train):
    env, train, test = all_layouts(name, n_train)
    for walls in np.concatenate([train, test]):
        assert walls[0].all() and walls[-1].all() and walls[:, 0].all() and walls[:, -1].all()
        start = env.eval_start(None)
        dist = bfs(walls, tuple(int(v) for v in start))
        assert set(dist) == free_cells(walls)
        for g in np.asarray(env.eval_goals(None)).astype(int):
            assert tuple(g) in dist, "every evaluation goal must be reachable"


def rooms_and_doors_fourrooms(walls):
    """Split the 11x11 layout into its four rooms (by flood fill with doors closed)."""
    # wall column/row: the interior column/row that is mostly wall
    c = int(np.argmax(walls[1:-1, 1:-1].sum(0))) + 1
    r = int(np.argmax(walls[1:-1, 1:-1].sum(1))) + 1
    doors = [(x, y) for (x, y) in free_cells(walls) if x == c or y == r]
    closed = walls.copy()
    for x, y in doors:
        closed[y, x] = True
    rooms = []
    remaining = free_cells(closed)
    while remaining:
        cell = min(remaining)
        room = set(bfs(closed, cell))
        rooms.append(room)
        remaining -= room
    return rooms, doors


def test_fourrooms_each_adjacent_pair_joined_by_exactly_one_door():
    _, train, test = all_layouts("fourrooms", 50)
    for walls in np.concatenate([train, test]):
        rooms, doors = rooms_and_doors_fourrooms(walls)
        assert len(rooms) == 4
        assert len(doors) == 4
        room_of = {cell: i for i, room in enumerate(rooms) for cell in room}
        pairs = []
        for x, y in doors:
            touching = {room_of[(x + dx, y + dy)] for dx, dy in DELTAS.values() if (x + dx, y + dy) in room_of}
            assert len(touching) == 2, "a door joins exactly two rooms"
            pairs.append(frozenset(touching))
        assert len(set(pairs)) == 4, "four distinct adjacent pairs, one door each"


def test_doors_one_door_per_wall():
    _, train, test = all_layouts("doors", 29)
    for walls in np.concatenate([train, test]):
        for x in (3, 5):
            assert (~walls[1:-1, x]).sum() == 1


@pytest.mark.parametrize("name,n_train", [("doors", 29), ("fourrooms", 50)])
def test_train_and_test_layouts_disjoint_and_distinct(name, n_train):
    _, train, test = all_layouts(name, n_train)
    tr = {w.tobytes() for w in train}
    te = {w.tobytes() for w in test}
    assert len(tr) == n_train and len(te) == 20
    assert not tr & te


def test_test_layouts_do_not_depend_on_n_train():
    _, _, t10 = all_layouts("fourrooms", 10)
    _, _, t30 = all_layouts("fourrooms", 30)
    np.testing.assert_array_equal(t10, t30)


@pytest.mark.parametrize("name", ["doors", "fourrooms"])
def test_step_matches_walls_under_vmap(name):
    """Random states and actions in many layouts at once: move unless the target is a wall."""
    env = zsbfm.make_env(name, n_train=20)
    ctxs = env.contexts("train")
    n = ctxs.walls.shape[0]
    key = jax.random.PRNGKey(0)
    k_reset, k_act = jax.random.split(key)
    states = jax.jit(jax.vmap(env.reset))(jax.random.split(k_reset, n), ctxs)
    walls = np.asarray(ctxs.walls)
    for i, k in enumerate(jax.random.split(k_act, 30)):
        actions = jax.random.randint(k, (n,), 0, 4)
        nxt = jax.jit(jax.vmap(env.step))(states, actions)
        for j in range(n):
            x, y = np.asarray(states.obs[j]).astype(int)
            dx, dy = DELTAS[int(actions[j])]
            expect = (x, y) if walls[j, y + dy, x + dx] else (x + dx, y + dy)
            assert tuple(np.asarray(nxt.obs[j]).astype(int)) == expect
            assert not walls[j, expect[1], expect[0]]
        states = nxt


@pytest.mark.parametrize("name", ["doors", "fourrooms"])
def test_revealed_features_are_the_cells_a_walk_entered_or_was_blocked_by(name):
    """env.revealed_features of a random walk: the interior cells it stood on, and those a move
    aimed at and the true wall map blocked, nothing else; batched walks, one map each."""
    from zsbfm.data import collect

    env = zsbfm.make_env(name, n_train=3)
    ds = jax.jit(lambda k: collect(env, k, env.contexts("train"), 2))(jax.random.PRNGKey(0))
    obs, act = np.asarray(ds.obs).astype(int), np.asarray(ds.action)
    walls = np.asarray(env.contexts("train").walls)[np.asarray(ds.context_id)]
    seen = np.asarray(jax.jit(jax.vmap(env.revealed_features))(ds.obs[:, :-1], ds.action, ds.obs[:, 1:]))
    for e in range(obs.shape[0]):
        expect = np.zeros(walls.shape[1:], bool)
        for t, a in enumerate(act[e]):
            (x, y), (dx, dy) = obs[e, t], DELTAS[int(a)]
            expect[y, x] = True
            if walls[e, y + dy, x + dx]:
                expect[y + dy, x + dx] = True
        expect[obs[e, -1, 1], obs[e, -1, 0]] = True
        np.testing.assert_array_equal(seen[e], expect[1:-1, 1:-1].reshape(-1))
        assert 0 < seen[e].sum() < seen[e].size


# doors runs the same GridWorld code on other layouts: in `make test-all`
@pytest.mark.parametrize("name", ["fourrooms", pytest.param("doors", marks=pytest.mark.slow)])
def test_a_move_enters_the_cell_it_points_at_exactly_when_that_cell_is_free(name):
    """env.pointed_cell is the agent's cell plus the action's direction, and env.cell_walls says
    what the move does there: from every free cell of every layout and for every action, the
    next cell is the pointed one if its cell_walls label is 0 and the agent's own if it is 1."""
    env = zsbfm.make_env(name, n_train=3)
    ctxs = env.contexts("train")
    S, A = env.size, len(DELTAS)
    cells = np.array([[x, y] for y in range(S) for x in range(S)], np.float32)
    for i in range(3):
        ctx = index_contexts(ctxs, i)
        walls = np.asarray(ctx.walls)
        labels = np.asarray(env.cell_walls(ctx))
        free = cells[~walls[cells[:, 1].astype(int), cells[:, 0].astype(int)]]
        obs, act = np.repeat(free, A, 0), np.tile(np.arange(A), len(free))
        pointed = np.asarray(env.pointed_cell(jnp.asarray(obs), jnp.asarray(act)))
        (x, y), (dx, dy) = obs.T.astype(int), np.array([DELTAS[a] for a in act]).T
        np.testing.assert_array_equal(pointed, (y + dy) * S + (x + dx))
        states = jax.vmap(lambda o: env.reset(jax.random.PRNGKey(0), ctx, start=o))(jnp.asarray(obs))
        nxt = np.asarray(jax.jit(jax.vmap(env.step))(states, jnp.asarray(act)).obs)
        entered = np.where(labels[pointed][:, None] == 1, obs, np.stack([x + dx, y + dy], -1))
        np.testing.assert_array_equal(nxt, entered)
        assert 0 < labels[pointed].sum() < len(pointed)


def test_goal_reward_and_time_limit():
    env = zsbfm.make_env("fourrooms", n_train=5, episode_len=5)
    ctx = index_contexts(env.contexts("train"), 0)
    s = env.reset(jax.random.PRNGKey(0), ctx, goal=jnp.array([2.0, 1.0]), start=jnp.array([1, 1]))
    s = env.step(s, 3)  # right, onto the goal
    assert float(s.reward) == 1.0 and bool(s.done)
    s = env.reset(jax.random.PRNGKey(0), ctx, start=jnp.array([1, 1]))
    for t in range(5):
        assert not bool(s.done)
        s = env.step(s, 0)
        assert float(s.reward) == 0.0
    assert bool(s.done) and int(s.t) == 5


def test_sample_contexts_are_valid_layouts():
    env = zsbfm.make_env("fourrooms")
    walls = np.asarray(jax.jit(lambda k: env.sample_contexts(k, 16))(jax.random.PRNGKey(3)).walls)
    assert walls.shape == (16, 11, 11)
    for w in walls:
        rooms, doors = rooms_and_doors_fourrooms(w)
        assert len(rooms) == 4 and len(doors) == 4
        assert set(bfs(w, (1, 1))) == free_cells(w)


def test_random_reset_starts_on_free_cells():
    env = zsbfm.make_env("doors")
    ctxs = env.contexts("train")
    states = jax.vmap(lambda k: env.reset(k, index_contexts(ctxs, 0)))(jax.random.split(jax.random.PRNGKey(1), 500))
    walls = np.asarray(ctxs.walls[0])
    xy = np.asarray(states.obs).astype(int)
    assert not walls[xy[:, 1], xy[:, 0]].any()
    assert len({tuple(p) for p in xy}) == len(free_cells(walls))  # all free cells drawn


def test_bad_env_arguments_raise():
    with pytest.raises(ValueError, match="unknown env 'humanoid'"):
        zsbfm.make_env("humanoid")
    with pytest.raises(ValueError, match="15 fixed train contexts, got n_train=20"):
        zsbfm.make_env("antwind", n_train=20)
    with pytest.raises(ValueError, match="n_train must be <= 29"):
        zsbfm.make_env("doors", n_train=40)
    with pytest.raises(ValueError, match="split must be"):
        zsbfm.make_env("doors").contexts("val")


def test_render_writes_png(tmp_path):
    from zsbfm.envs.render import render_layouts

    env = zsbfm.make_env("fourrooms")
    w = np.asarray(env.contexts("test").walls[0])
    path = render_layouts(str(tmp_path / "l.png"), [
        dict(walls=w, values=np.random.rand(11, 11), actions=np.zeros((11, 11), int), start=(1, 1),
             goals=[(8, 8)], title="x")])
    with open(path, "rb") as f:
        assert f.read(8) == b"\x89PNG\r\n\x1a\n"


def test_context_coverage_finds_the_doors_and_what_an_episode_reveals():
    """experiments/fb_diagnostics/context_coverage.py: the doors of a Four-Rooms layout built
    from its parameters, and the cells an episode reveals (visited, or bumped into)."""
    import os
    import sys

    sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "experiments", "fb_diagnostics"))
    from context_coverage import doors, revealed
    from zsbfm.envs.gridworld import doors_walls, fourrooms_walls

    c, r, du, dd, dl, dr = 4, 6, 2, 8, 1, 7
    walls = np.asarray(fourrooms_walls(jnp.asarray([c, r, du, dd, dl, dr])))
    assert sorted(doors(walls)) == sorted([(du, c), (dd, c), (r, dl), (r, dr)])
    assert sorted(doors(np.asarray(doors_walls(jnp.asarray([2, 6]))))) == [(2, 3), (6, 5)]
    # from (1, 1): right to (2, 1), then up into the border (stays: the wall (2, 0), not
    # shown: the border is a wall in every layout), then down to (2, 2)
    cells = jnp.asarray([[1, 1], [2, 1], [2, 1], [2, 2]], jnp.float32)
    seen = np.asarray(revealed(zsbfm.make_env("fourrooms"), cells, jnp.asarray([3, 0, 1])))
    assert set(zip(*np.nonzero(seen))) == {(1, 1), (1, 2), (2, 2)}  # (y, x)


@pytest.mark.parametrize("name", ["doors", "fourrooms"])
def test_cells_to_features_reads_the_interior_cells_in_the_wall_maps_order(name):
    """env.cells_to_features of a value per cell_index is the value of each interior cell
    (x, y) in 1..size-2, row-major, the order of context_features, so that the wall map per
    cell maps onto context_features itself."""
    env = zsbfm.make_env(name, n_train=3)
    S = env.size
    got = np.asarray(env.cells_to_features(jnp.arange(env.n_cells)[None].repeat(2, 0)))
    np.testing.assert_array_equal(got, [[y * S + x for y in range(1, S - 1) for x in range(1, S - 1)]] * 2)
    ctxs = env.contexts("train")
    for i in range(3):
        ctx = index_contexts(ctxs, i)
        np.testing.assert_array_equal(np.asarray(env.cells_to_features(env.cell_walls(ctx))),
                                      np.asarray(env.context_features(ctx)))
