"""Pictures of gridworld layouts: walls, an optional value map, greedy-policy arrows."""

from __future__ import annotations

import numpy as np

from zsbfm.envs.gridworld import ACTION_DELTAS


def draw_grid(ax, walls, values=None, actions=None, start=None, goals=(), trajectory=None,
              title=None):
    """Draw one layout on a matplotlib axis.

    walls:      bool[H, W] (walls[y, x]).
    values:     optional float[H, W] value map, shown on free cells.
    actions:    optional int[H, W] greedy action per cell, shown as arrows on free cells.
    start:      optional (x, y); goals: iterable of (x, y); trajectory: optional float[T, 2].
    """
    walls = np.asarray(walls, bool)
    h, w = walls.shape
    if values is not None:
        v = np.ma.masked_array(np.asarray(values, float), mask=walls)
        im = ax.imshow(v, cmap="viridis", origin="upper")
        cbar = ax.figure.colorbar(im, ax=ax, fraction=0.046, pad=0.04)
        cbar.set_label("V(s) = max_a Q(s, a)", fontsize=7)
    ax.imshow(np.ma.masked_array(np.ones_like(walls, float), mask=~walls), cmap="gray_r",
              vmin=0, vmax=1.5, origin="upper")
    if actions is not None:
        ys, xs = np.nonzero(~walls)
        d = ACTION_DELTAS[np.asarray(actions)[ys, xs]]
        # imshow's y axis points down, so a +1 dy is drawn downwards.
        ax.quiver(xs, ys, d[:, 0], -d[:, 1], color="white", scale=25, width=0.006)
    if trajectory is not None:
        tr = np.asarray(trajectory)
        ax.plot(tr[:, 0], tr[:, 1], color="orange", lw=1.5)
    if start is not None:
        ax.scatter([start[0]], [start[1]], marker="^", color="red", s=80, zorder=3)
    for g in goals:
        ax.scatter([g[0]], [g[1]], marker="s", color="lime", s=80, zorder=3)
    ax.set_xticks(range(w))
    ax.set_yticks(range(h))
    ax.tick_params(labelsize=6)
    if title:
        ax.set_title(title, fontsize=9)


def render_layouts(path, panels, ncols: int | None = None):
    """Save a grid of layouts to a PNG at `path`.

    panels: a list of dicts, each the keyword arguments of `draw_grid` (walls=..., ...).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(panels)
    ncols = ncols or n
    nrows = -(-n // ncols)
    fig, axes = plt.subplots(nrows, ncols, figsize=(3.4 * ncols, 3.2 * nrows), squeeze=False)
    for ax in axes.flat[n:]:
        ax.axis("off")
    for ax, panel in zip(axes.flat, panels):
        draw_grid(ax, **panel)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def render_mazes(path, walls, trajectories=None, starts=None, goals=None, unit: float = 4.0,
                 titles=None, ncols: int | None = None):
    """Pointmass mazes with trajectories, one panel per maze, to a PNG at `path`.

    walls: bool[n, H, W] (walls[y, x], cells); trajectories: optional list (per maze) of
    float[T, 2] world-unit paths, or of lists of them; starts / goals: optional float[n, 2].
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    walls = np.asarray(walls, bool)
    n = len(walls)
    ncols = ncols or min(n, 5)
    nrows = -(-n // ncols)
    fig, axes = plt.subplots(nrows, ncols, figsize=(3 * ncols, 3 * nrows), squeeze=False)
    for ax in axes.flat[n:]:
        ax.axis("off")
    for i, ax in zip(range(n), axes.flat):
        h, w = walls[i].shape
        ax.imshow(walls[i], cmap="gray_r", vmin=0, vmax=1.5, origin="upper", extent=(0, w * unit, h * unit, 0))
        paths = [] if trajectories is None else trajectories[i]
        paths = [paths] if isinstance(paths, np.ndarray) and paths.ndim == 2 else paths
        for tr in paths:
            tr = np.asarray(tr)
            ax.plot(tr[:, 0], tr[:, 1], lw=1.0, alpha=0.8)
        if starts is not None:
            ax.scatter(*np.asarray(starts[i]), marker="^", color="red", s=60, zorder=3)
        if goals is not None:
            ax.add_patch(plt.Circle(tuple(np.asarray(goals[i])), 1.0, color="lime", zorder=3))
        ax.set_xticks([])
        ax.set_yticks([])
        if titles:
            ax.set_title(titles[i], fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
