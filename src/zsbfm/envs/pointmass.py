"""Randomized Pointmass in jax.numpy: a damped point mass pushed through a hidden maze.

Maze: an 8x8 map of cells (border included), each cell `UNIT` = 4 world units wide, so
the world is [0, 32]^2 and cell (i, j) covers [4i, 4i+4) x [4j, 4j+4). `walls[j, i]` is
True for a wall (indexed [y, x], as in the gridworlds). The observation is the position
(x, y) only: the maze is hidden.

Dynamics, per env step, `SUBSTEPS` substeps of length `DT`, force f = ACCEL * clip(a, -1, 1):
    dv/dt = -DAMPING v + f, integrated exactly for the constant force of a substep:
    v1 = v0 e + (f / k)(1 - e),   x1 = x0 + (f / k) dt + (v0 - f / k)(1 - e) / k,  e = exp(-k dt).
Collisions: the move of a substep is applied one axis at a time; an axis whose move would
end inside a wall cell is not taken and its velocity is zeroed. The terminal speed
ACCEL * sqrt(2) / DAMPING = 5.7 units/time moves at most 0.29 units per substep, far less
than a cell, so the mass can never tunnel through a wall nor end inside one.

Maze generator (the authors', REFERENCE.md): a 6x6 interior, each cell open with p = 0.5;
two cellular-automata passes (an open cell becomes a wall if more than 6 of its 8
neighbours are open); accepted if 53-88% of the interior is open, all open cells are
4-connected, the BFS distance from the start (the first open cell, row-major) to the
farthest cell is under 13, and it is not a duplicate. Fixed mazes are generated on the
host with numpy from fixed seeds (30 train, 20 test, disjoint); `sample_contexts` draws
from a fixed pool of 128 generated mazes, none of them a test maze.

Evaluation: start at the centre of the first open cell (row-major), goal at the centre of
the BFS-farthest reachable cell; success = within GOAL_RADIUS = 1.0 of the goal.
Behaviour data: sticky random directions (a new uniform direction with probability 1/10
per step) plus Gaussian noise (sigma 0.3), clipped to [-1, 1]^2.
"""

from __future__ import annotations

import dataclasses
import functools
from collections import deque

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from zsbfm.envs.base import EnvBase, EnvState
from zsbfm.envs.registry import EnvSpec, register

Array = jax.Array

SIZE = 8             # cells per side, border included
UNIT = 4.0           # world units per cell
DT = 0.05            # substep length
SUBSTEPS = 5
DAMPING = 1.0
ACCEL = 4.0
GOAL_RADIUS = 1.0
STICKY_P = 0.1       # probability per step of drawing a new behaviour direction
NOISE = 0.3          # behaviour action noise (std)
N_TEST, POOL = 20, 128
_TEST_SEED, _TRAIN_SEED, _POOL_SEED = 2024, 0, 7


@struct.dataclass
class MazeContext:
    """One maze. walls: bool[8, 8], True = wall, indexed walls[y, x] (cells)."""

    walls: Array


@struct.dataclass
class PointState:
    pos: Array  # float32[2], world units
    vel: Array  # float32[2]


# --- maze generation (host, numpy) ------------------------------------------------------

def bfs(open_cells: np.ndarray, start: tuple[int, int]) -> np.ndarray:
    """4-neighbour BFS distances (cells; -1 = unreachable) over open_cells[y, x] from (x, y)."""
    dist = -np.ones(open_cells.shape, int)
    dist[start[1], start[0]] = 0
    q = deque([start])
    while q:
        x, y = q.popleft()
        for dx, dy in ((0, -1), (0, 1), (-1, 0), (1, 0)):
            nx, ny = x + dx, y + dy
            if 0 <= ny < open_cells.shape[0] and 0 <= nx < open_cells.shape[1] \
                    and open_cells[ny, nx] and dist[ny, nx] < 0:
                dist[ny, nx] = dist[y, x] + 1
                q.append((nx, ny))
    return dist


def first_open(open_cells: np.ndarray) -> tuple[int, int]:
    y, x = np.argwhere(open_cells)[0]  # row-major
    return int(x), int(y)


def maze_ok(walls: np.ndarray) -> bool:
    """The generator's acceptance test on a full 8x8 map (independent of how it was drawn)."""
    interior = ~walls[1:-1, 1:-1]
    if not (walls[0].all() and walls[-1].all() and walls[:, 0].all() and walls[:, -1].all()):
        return False
    if not 0.53 <= interior.mean() <= 0.88:
        return False
    dist = bfs(~walls, first_open(~walls))
    return bool((dist[~walls] >= 0).all() and dist.max() < 13)


def generate_maze(rng: np.random.Generator) -> np.ndarray:
    """One accepted maze: walls bool[8, 8]."""
    while True:
        interior = rng.random((SIZE - 2, SIZE - 2)) < 0.5
        for _ in range(2):
            padded = np.pad(interior, 1).astype(int)
            neighbours = sum(np.roll(np.roll(padded, dy, 0), dx, 1)
                             for dy in (-1, 0, 1) for dx in (-1, 0, 1) if (dx, dy) != (0, 0))[1:-1, 1:-1]
            interior = interior & ~(neighbours > 6)
        walls = np.ones((SIZE, SIZE), bool)
        walls[1:-1, 1:-1] = ~interior
        if interior.any() and maze_ok(walls):
            return walls


def draw_mazes(seed: int, n: int, exclude: set) -> tuple[np.ndarray, set]:
    rng, seen, out = np.random.default_rng(seed), set(exclude), []
    while len(out) < n:
        w = generate_maze(rng)
        if w.tobytes() not in seen:
            seen.add(w.tobytes())
            out.append(w)
    return np.stack(out), seen


@functools.lru_cache(maxsize=None)
def fixed_mazes(n_train: int) -> tuple[np.ndarray, np.ndarray]:
    """(train bool[n_train, 8, 8], test bool[20, 8, 8]); test depends only on its seed."""
    test, seen = draw_mazes(_TEST_SEED, N_TEST, set())
    train, _ = draw_mazes(_TRAIN_SEED, n_train, seen)
    return train, test


@functools.lru_cache(maxsize=None)
def maze_pool() -> np.ndarray:
    """Mazes for `sample_contexts`: never one of the 20 test mazes."""
    _, test = fixed_mazes(1)
    return draw_mazes(_POOL_SEED, POOL, {w.tobytes() for w in test})[0]


# --- jnp helpers ----------------------------------------------------------------------------

def cell_of(pos: Array) -> Array:
    return jnp.floor(pos / UNIT).astype(jnp.int32)


def is_wall(walls: Array, pos: Array) -> Array:
    c = jnp.clip(cell_of(pos), 0, SIZE - 1)
    return walls[c[1], c[0]]


def bfs_jnp(walls: Array, start_cell: Array) -> Array:
    """BFS distances (cells) from start_cell (x, y) over open cells; large = unreachable."""
    big = SIZE * SIZE
    dist = jnp.full((SIZE, SIZE), big).at[start_cell[1], start_cell[0]].set(0)

    def relax(_, d):
        pad = jnp.pad(d, 1, constant_values=big)
        nb = jnp.minimum(jnp.minimum(pad[:-2, 1:-1], pad[2:, 1:-1]), jnp.minimum(pad[1:-1, :-2], pad[1:-1, 2:]))
        return jnp.where(walls, big, jnp.minimum(d, nb + 1))

    return jax.lax.fori_loop(0, big, relax, dist)


def integrate(pos: Array, vel: Array, force: Array, dt: float = DT):
    """Exact solution of dv/dt = -DAMPING v + force over dt (free space)."""
    k = DAMPING
    e = jnp.exp(-k * dt)
    v_inf = force / k
    return pos + v_inf * dt + (vel - v_inf) * (1.0 - e) / k, v_inf + (vel - v_inf) * e


@dataclasses.dataclass(frozen=True)
class PointMass(EnvBase):
    """Randomized Pointmass (see the module docstring). Hashable: usable as a static arg."""

    n_train: int = 30
    episode_len: int = 250

    name = "pointmass"
    discrete = False
    obs_dim = 2
    n_actions = 0
    action_dim = 2
    obs_low = (0.0, 0.0)
    obs_high = (SIZE * UNIT, SIZE * UNIT)
    goal_radius = GOAL_RADIUS
    n_cells = SIZE * SIZE   # cells of the map, border included (Config.enc_cell_tokens)

    def __post_init__(self):
        if self.n_train < 1:
            raise ValueError(f"n_train must be >= 1, got {self.n_train}")
        if self.episode_len < 1:
            raise ValueError(f"episode_len must be >= 1, got {self.episode_len}")

    def cell_index(self, obs: Array) -> Array:
        """Row-major index in [0, n_cells) of the map cell holding each observation [..., 2]."""
        c = jnp.clip(cell_of(obs), 0, SIZE - 1)
        return c[..., 1] * SIZE + c[..., 0]

    # -- contexts ---------------------------------------------------------------------------
    def contexts(self, split: str) -> MazeContext:
        if split not in ("train", "test"):
            raise ValueError(f"split must be 'train' or 'test', got {split!r}")
        train, test = fixed_mazes(self.n_train)
        return MazeContext(walls=jnp.asarray(train if split == "train" else test))

    def context_features(self, ctx: MazeContext) -> Array:
        """The maze as a vector: its interior wall map (the oracle's "walls" context)."""
        return ctx.walls[1:-1, 1:-1].reshape(-1).astype(jnp.float32)

    def sample_contexts(self, key: Array, n: int) -> MazeContext:
        """n mazes drawn from a fixed pool of generated mazes (jittable; never a test maze,
        may equal a train maze)."""
        idx = jax.random.randint(key, (n,), 0, POOL)
        return MazeContext(walls=jnp.asarray(maze_pool())[idx])

    def start_cell(self, ctx: MazeContext) -> Array:
        flat = jnp.argmax(~ctx.walls.reshape(-1))  # first open cell, row-major
        return jnp.stack([flat % SIZE, flat // SIZE])

    def eval_start(self, ctx: MazeContext) -> Array:
        return (self.start_cell(ctx) + 0.5).astype(jnp.float32) * UNIT

    def eval_goals(self, ctx: MazeContext) -> Array:
        """[1, 2]: the centre of the BFS-farthest reachable cell from the start."""
        dist = bfs_jnp(ctx.walls, self.start_cell(ctx))
        flat = jnp.argmax(jnp.where(dist < SIZE * SIZE, dist, -1).reshape(-1))
        return ((jnp.stack([flat % SIZE, flat // SIZE]) + 0.5) * UNIT).astype(jnp.float32)[None]

    # Goal-reaching protocols (zsbfm.evaluate), the first one the official score:
    #   "paper": the first open cell to the BFS-farthest one (the authors');
    #   "dense": the same start, every other open cell's centre a goal.
    eval_protocols = ("paper", "dense")

    def eval_tasks(self, ctx: MazeContext, protocol: str, key: Array) -> tuple[Array, Array, Array]:
        """(starts float32[G, 2], goals float32[G, 2], valid bool[G]) of a protocol in one maze."""
        start = self.eval_start(ctx)
        if protocol == "paper":
            goals = self.eval_goals(ctx)
            return jnp.broadcast_to(start, goals.shape), goals, jnp.ones(goals.shape[0], bool)
        if protocol == "dense":
            y, x = jnp.mgrid[0:SIZE, 0:SIZE]
            cells = jnp.stack([x.reshape(-1), y.reshape(-1)], -1)
            goals = ((cells + 0.5) * UNIT).astype(jnp.float32)
            flat_start = self.start_cell(ctx)
            valid = ~ctx.walls.reshape(-1) & ~jnp.all(cells == flat_start, -1)
            return jnp.broadcast_to(start, goals.shape), goals, valid
        raise ValueError(f"unknown protocol {protocol!r} for pointmass: expected one of {self.eval_protocols}")

    # -- dynamics ---------------------------------------------------------------------------
    def reset(self, key: Array, ctx: MazeContext, goal: Array | None = None,
              start: Array | None = None) -> EnvState:
        """At rest at `start` (x, y), or uniformly inside a random open cell."""
        if start is None:
            k_cell, k_pos = jax.random.split(key)
            cell = jax.random.categorical(k_cell, jnp.where(~ctx.walls.reshape(-1), 0.0, -jnp.inf))
            xy = jnp.stack([cell % SIZE, cell // SIZE]).astype(jnp.float32)
            pos = (xy + jax.random.uniform(k_pos, (2,), minval=0.05, maxval=0.95)) * UNIT
        else:
            pos = jnp.asarray(start, jnp.float32)
        has_goal = goal is not None
        goal = jnp.zeros(2, jnp.float32) if goal is None else jnp.asarray(goal, jnp.float32)
        inner = PointState(pos=pos, vel=jnp.zeros(2, jnp.float32))
        return EnvState(obs=pos, reward=jnp.zeros((), jnp.float32), done=jnp.zeros((), bool),
                        t=jnp.zeros((), jnp.int32), goal=goal, has_goal=jnp.asarray(has_goal),
                        ctx=ctx, inner=inner)

    def substep(self, walls: Array, p: PointState, force: Array) -> PointState:
        new_pos, new_vel = integrate(p.pos, p.vel, force)
        # one axis at a time: slide along walls, stop dead against them
        x_try = jnp.stack([new_pos[0], p.pos[1]])
        x_ok = ~is_wall(walls, x_try)
        pos = jnp.where(x_ok, x_try, p.pos)
        y_try = jnp.stack([pos[0], new_pos[1]])
        y_ok = ~is_wall(walls, y_try)
        pos = jnp.where(y_ok, y_try, pos)
        vel = new_vel * jnp.stack([x_ok, y_ok]).astype(jnp.float32)
        return PointState(pos=pos, vel=vel)

    def step(self, state: EnvState, action: Array) -> EnvState:
        force = ACCEL * jnp.clip(jnp.asarray(action, jnp.float32), -1.0, 1.0)
        inner = jax.lax.fori_loop(0, SUBSTEPS, lambda _, p: self.substep(state.ctx.walls, p, force), state.inner)
        reached = state.has_goal & (jnp.linalg.norm(inner.pos - state.goal) < GOAL_RADIUS)
        t = state.t + 1
        return state.replace(obs=inner.pos, reward=reached.astype(jnp.float32),
                             done=reached | (t >= self.episode_len), t=t, inner=inner)

    def random_action(self, key: Array) -> Array:
        return jax.random.uniform(key, (2,), minval=-1.0, maxval=1.0)

    def behaviour_actions(self, key: Array, length: int) -> Array:
        """Open-loop sticky random directions plus noise: float32[length, 2] in [-1, 1]."""
        k_dir, k_switch, k_noise = jax.random.split(key, 3)
        angles = jax.random.uniform(k_dir, (length,), maxval=2 * jnp.pi)
        switch = (jax.random.uniform(k_switch, (length,)) < STICKY_P).at[0].set(True)
        # the direction in force at step t is the one drawn at the last switch <= t
        last = jax.lax.cummax(jnp.where(switch, jnp.arange(length), 0))
        theta = angles[last]
        a = jnp.stack([jnp.cos(theta), jnp.sin(theta)], -1)
        return jnp.clip(a + NOISE * jax.random.normal(k_noise, (length, 2)), -1.0, 1.0)


# 30 train mazes x 133 episodes x 250 steps = 1e6 transitions; contexts are 100-step windows.
# f_arch="normed_trunk" (F before f_arch existed): the Pointmass tables were measured with it.
register(EnvSpec(
    name="pointmass", make=PointMass, episode_len=250, discrete=False, n_train=30, cell_map=True, binary_context=True,
    presets={
        "cpu": dict(n_train_layouts=30, episodes_per_layout=133, episode_len=250, eval_episode_len=250,
                    context_len=100, obs_encoding="raw", gamma=0.98, f_arch="normed_trunk"),
        "paper": dict(n_train_layouts=30, episodes_per_layout=133, episode_len=250, eval_episode_len=250,
                      context_len=100, obs_encoding="raw", d=150, f_pre_hidden=(1024,), f_pre_out=512,
                      f_hidden=(1024, 1024), b_hidden=(256, 256, 256), actor_hidden=(1024, 1024), lr=1e-4,
                      batch_size=1024, gamma=0.99, tau=0.05, steps=1_000_000, chunk_steps=10_000,
                      kappa=100.0, feat_hidden=(512, 512))},
    description="continuous point mass in a randomized 8x8 maze"))
