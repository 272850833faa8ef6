"""Top-down pictures of layouts (matplotlib, Agg): arena, border, obstacles, spawn regions.

Fixed obstacles are drawn solid, the random obstacles of one seed hatched in another colour,
spawn regions as translucent rectangles. Coordinates are the layout frame (m).
"""

from __future__ import annotations

import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.patches as mpatches  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from .io_utils import atomic_path  # noqa: E402
from .layout import Cylinder, Layout, Wall  # noqa: E402
from .palette import BORDER_RGBA, OBSTACLE_RGBA, ROLE_RGBA, hex_colour  # noqa: E402

FIXED_COLOR = hex_colour(OBSTACLE_RGBA["fixed"])
RANDOM_COLOR = hex_colour(OBSTACLE_RGBA["random"])
BORDER_COLOR = hex_colour(BORDER_RGBA)
OUTSIDE_COLOR = "#c9ccd1"
SPAWN_COLORS = {"pursuers": hex_colour(ROLE_RGBA["pursuer"]), "evaders": hex_colour(ROLE_RGBA["evader"])}


def _obstacle_patch(o, color: str, hatch: str | None = None) -> mpatches.Patch:
    if isinstance(o, Wall):
        o = o.as_box()
    style = dict(facecolor=color, edgecolor="black", linewidth=0.6, hatch=hatch)
    if isinstance(o, Cylinder):
        return mpatches.Circle(o.center, o.radius, **style)
    hx, hy = o.size[0] / 2, o.size[1] / 2
    c, s = math.cos(o.yaw), math.sin(o.yaw)
    corner = (o.center[0] - c * hx + s * hy, o.center[1] - s * hx - c * hy)  # the local (-hx, -hy) corner
    return mpatches.Rectangle(corner, o.size[0], o.size[1], angle=math.degrees(o.yaw), **style)


def _draw_border(ax, layout: Layout) -> None:
    """Shade the arena outside the border and outline the border."""
    w, h = layout.width, layout.height
    ax.add_patch(mpatches.Rectangle((0, 0), w, h, facecolor=OUTSIDE_COLOR, edgecolor="none", zorder=0))
    seg = layout.border()
    outline = np.vstack([seg[:, :2], seg[:1, :2]])
    ax.add_patch(mpatches.Polygon(outline[:-1], closed=True, facecolor="white", edgecolor=BORDER_COLOR, linewidth=2.0, zorder=1))
    ax.add_patch(mpatches.Rectangle((0, 0), w, h, fill=False, edgecolor="#888888", linestyle="--", linewidth=0.8, zorder=1))


def draw_layout(ax, layout: Layout, random_obstacles: tuple = (), random_label: str = "random obstacles") -> None:
    """Draw `layout` on a matplotlib axes; `random_obstacles` are drawn hatched as extra obstacles,
    and so are a placed layout's own random ones (`Layout.n_random`)."""
    _draw_border(ax, layout)
    n_fixed = len(layout.obstacles) - layout.n_random
    fixed, random_obstacles = layout.obstacles[:n_fixed], layout.obstacles[n_fixed:] + tuple(random_obstacles)
    for name, region in (("pursuers", layout.spawn_pursuers), ("evaders", layout.spawn_evaders)):
        color = SPAWN_COLORS[name]
        ax.add_patch(mpatches.Rectangle((region.x[0], region.y[0]), region.x[1] - region.x[0], region.y[1] - region.y[0],
                                        facecolor=color, alpha=0.18, edgecolor=color, linewidth=1.2, zorder=2))
        if region.is_point:  # a fixed start: a rectangle of no size would not show
            ax.plot([region.x[0]], [region.y[0]], marker="o", markersize=7, color=color, zorder=4)
    for o in fixed:
        patch = _obstacle_patch(o, FIXED_COLOR)
        patch.set_zorder(3)
        ax.add_patch(patch)
    for o in random_obstacles:
        patch = _obstacle_patch(o, RANDOM_COLOR, hatch="///")
        patch.set_zorder(3)
        ax.add_patch(patch)
    handles = []
    if fixed:
        handles.append(mpatches.Patch(facecolor=FIXED_COLOR, edgecolor="black", label=f"fixed obstacles ({len(fixed)})"))
    if random_obstacles:
        handles.append(mpatches.Patch(facecolor=RANDOM_COLOR, edgecolor="black", hatch="///",
                                      label=f"{random_label} ({len(random_obstacles)})"))
    handles += [
        mpatches.Patch(facecolor=SPAWN_COLORS["pursuers"], alpha=0.35, label="pursuer spawn"),
        mpatches.Patch(facecolor=SPAWN_COLORS["evaders"], alpha=0.35, label="evader spawn"),
    ]
    ax.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, -0.07), ncol=2, fontsize=8, frameon=False)
    margin = 0.1
    ax.set_xlim(-margin, layout.width + margin)
    ax.set_ylim(-margin, layout.height + margin)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.grid(True, linewidth=0.3, alpha=0.5)
    ax.set_axisbelow(True)


def preview_layout(layout: Layout, seed: int, count: int | None = None, passage_clearance: float = 0.0,
                   passage_source: str = "obstacle_clearance", count_source: str | None = None) -> Layout:
    """`layout` with the random obstacles an episode of seed `seed` draws (Layout.with_random_obstacles).

    passage_clearance (m): the task's obstacle_clearance; above 0.15 m the env draws placements
    that close a passage again, and so does this. Raises LayoutError if they do not fit, naming
    `count_source` (where `count` came from; default: the file's random_obstacles.count).
    It tries as many placements as an episode's reset (layout_random.EPISODE_RESTARTS), so a seed
    whose room an episode finds only after many draws is drawn as that episode has it.
    """
    from .layout_random import EPISODE_RESTARTS

    return layout.with_random_obstacles(np.random.default_rng(seed), count, count_source=count_source,
                                        passage_clearance=passage_clearance, passage_source=passage_source,
                                        restarts=EPISODE_RESTARTS)


def save_layout_png(layout: Layout, path: str | Path, seed: int | None = 0, count: int | None = None, dpi: int = 120,
                    passage_clearance: float = 0.0, passage_source: str = "obstacle_clearance",
                    count_source: str | None = None) -> Path:
    """Write a top-down PNG of `layout` atomically; with a seed, its random obstacles are drawn too.

    count: random obstacles to place (default: the layout's random_obstacles.count);
    passage_clearance, passage_source, count_source: as for `preview_layout`. Raises LayoutError if they do not fit.
    """
    extra: tuple = ()
    label = "random obstacles"
    if seed is not None:
        placed = preview_layout(layout, seed, count, passage_clearance, passage_source, count_source)
        extra = placed.obstacles[len(layout.obstacles):]
        label = f"random obstacles, seed {seed}"
    fig, ax = plt.subplots(figsize=(4.2 * max(layout.width / layout.height, 0.6) + 1.6, 6.4), dpi=dpi)
    try:
        draw_layout(ax, layout, extra, label)
        ax.set_title(f"layout '{layout.name}'  {layout.width:g} x {layout.height:g} m, {layout.boundary.kind} border", fontsize=10)
        fig.tight_layout()
        with atomic_path(path) as tmp:
            fig.savefig(tmp, format="png")
    finally:
        plt.close(fig)
    return Path(path)
