"""Layouts: file round trips, random obstacles, malformed and impossible files, the `layout` CLI."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np
import pytest
import yaml

from pursuit_cli import main
from pursuit_mj.config import default_config
from pursuit_mj.env import PursuitEnv, episode_seed
from pursuit_mj.geometry import ObstacleSet, inside_boundary, obstacle_distance
from pursuit_mj.layout import (
    N_BUILTIN,
    Cylinder,
    LayoutError,
    builtin_layout_path,
    layout_from_dict,
    layout_to_dict,
    load_layout,
    save_layout,
)
from pursuit_mj.layout_check import check_passages, grid_components
from pursuit_mj.layout_random import EPISODE_RESTARTS

SPAWN = {"pursuers": {"x": [0.2, 3.4], "y": [0.2, 0.8]}, "evaders": {"x": [0.2, 3.4], "y": [4.2, 4.8]}}


def base_dict(**changes) -> dict:
    data = {"name": "t", "arena": {"width": 3.6, "height": 5.0}, "boundary": "rectangle", "obstacles": [],
            "random_obstacles": {"count": 3, "kinds": ["box", "cylinder"], "size": [0.15, 0.4]}, "spawn": SPAWN}
    data.update(changes)
    return data


POLYGON = base_dict(name="hexagon", boundary={"polygon": [[0.6, 0.0], [3.0, 0.0], [3.6, 2.5], [3.0, 5.0], [0.6, 5.0], [0.0, 2.5]]},
                    obstacles=[{"box": {"center": [1.8, 2.5], "size": [1.0, 0.2], "yaw": 0.3}}, {"wall": {"from": [1.0, 3.3], "to": [2.6, 3.3], "thickness": 0.04}}],
                    spawn={"pursuers": {"x": [0.8, 2.8], "y": [0.2, 0.8]}, "evaders": {"x": [0.8, 2.8], "y": [4.2, 4.8]}})
CIRCLE = base_dict(name="round", arena={"width": 4.0, "height": 4.0}, boundary={"circle": {"center": [2.0, 2.0], "radius": 1.9}},
                   obstacles=[{"cylinder": {"center": [2.0, 2.0], "radius": 0.25}}],
                   spawn={"pursuers": {"x": [1.2, 2.8], "y": [0.5, 1.0]}, "evaders": {"x": [1.2, 2.8], "y": [3.0, 3.5]}})


def round_trip(layout, path: Path):
    save_layout(layout, path)
    again = load_layout(path)
    # a saved file lists placed random obstacles as its own: they are fixed ones once loaded
    assert dataclasses.replace(again, source=layout.source) == dataclasses.replace(layout, n_random=0)
    text = path.read_text()
    save_layout(again, path)
    assert path.read_text() == text  # file -> object -> file is stable
    return again


@pytest.mark.parametrize("index", range(N_BUILTIN))
def test_built_in_layouts_round_trip(index, tmp_path):
    layout = load_layout(index)
    round_trip(layout, tmp_path / "copy.yaml")
    assert layout_to_dict(load_layout(tmp_path / "copy.yaml")) == layout_to_dict(layout)


@pytest.mark.parametrize("data", [POLYGON, CIRCLE], ids=["polygon", "circle"])
def test_polygon_and_circle_layouts_round_trip(data, tmp_path):
    path = tmp_path / f"{data['name']}.yaml"
    path.write_text(yaml.safe_dump(data))
    layout = load_layout(path)
    assert layout.boundary.kind == next(iter(data["boundary"]))
    round_trip(layout, tmp_path / "again.yaml")
    # random obstacles resolved into concrete ones round-trip as well
    round_trip(layout.with_random_obstacles(np.random.default_rng(0)), tmp_path / "resolved.yaml")


@pytest.mark.parametrize("name", ["1e6", "2E-3", "010", "1:30", "yes"])
def test_a_saved_layout_whose_name_reads_as_a_number_loads_again(name, tmp_path):
    # the loader reads 1e6 as a number (YAML 1.2); a name written unquoted came back as 1000000.0
    round_trip(layout_from_dict(base_dict(name=name)), tmp_path / "named.yaml")


def test_clockwise_polygon_is_stored_counter_clockwise():
    cw = base_dict(boundary={"polygon": [[0, 0], [0, 5], [3.6, 5], [3.6, 0]]})
    layout = layout_from_dict(cw)
    pts = np.array(layout.boundary.points)
    area = 0.5 * np.sum(pts[:, 0] * np.roll(pts[:, 1], -1) - np.roll(pts[:, 0], -1) * pts[:, 1])
    assert area > 0
    assert inside_boundary(layout, np.array([[1.8, 2.5]]))[0] and not inside_boundary(layout, np.array([[4.0, 2.5]]))[0]


def test_layout_references_resolve_by_index_or_path(tmp_path):
    assert load_layout("2") == load_layout(2)
    assert load_layout(builtin_layout_path(1)).name == "walls"
    with pytest.raises(LayoutError, match=r"layout 9: no built-in layout with this index \(valid: 0-3\)"):
        load_layout(9)
    with pytest.raises(LayoutError, match="no such file"):
        load_layout(tmp_path / "missing.yaml")


# ----------------------------------------------------------------------------- random obstacles


@pytest.mark.parametrize("index", range(N_BUILTIN))
def test_random_obstacles_are_seeded_and_keep_off_spawn_regions_and_each_other(index):
    layout = load_layout(index)
    a = layout.with_random_obstacles(np.random.default_rng(3))
    b = layout.with_random_obstacles(np.random.default_rng(3))
    c = layout.with_random_obstacles(np.random.default_rng(4))
    assert a == b and a != c
    extra = a.obstacles[len(layout.obstacles):]
    assert len(extra) == layout.random_obstacles.count and a.random_obstacles.count == 0
    lo, hi = layout.random_obstacles.size
    for k, o in enumerate(extra):
        size = 2 * o.radius if isinstance(o, Cylinder) else max(o.size)
        assert lo - 1e-9 <= size <= hi + 1e-9
        assert inside_boundary(layout, np.array([o.center]))[0]
        alone = dataclasses.replace(layout, obstacles=(o,))
        others = dataclasses.replace(layout, obstacles=layout.obstacles + extra[:k] + extra[k + 1:])
        surface = _outline(alone)
        assert obstacle_distance(surface, ObstacleSet.from_layout(others, include_border=False), with_border=False).min() > 0.0
        for region in (layout.spawn_pursuers, layout.spawn_evaders):
            inside = (surface[:, 0] >= region.x[0]) & (surface[:, 0] <= region.x[1]) & (surface[:, 1] >= region.y[0]) & (surface[:, 1] <= region.y[1])
            assert not inside.any()


def _placed_one_draw_at_a_time(layout, rng, count, clearance=0.3):
    """The placement rule in its plainest form: draw a candidate, keep it if it fits, else draw
    again (up to 1000 draws an obstacle, 10 starts over); None if there is no room."""
    from pursuit_mj.geometry import border_distance
    from pursuit_mj.layout import Box
    from pursuit_mj.layout_random import _spawn_distance

    spec, border = layout.random_obstacles, layout.border()
    for _ in range(10):
        placed = []
        for _ in range(count):
            for _ in range(1000):
                kind = spec.kinds[rng.integers(len(spec.kinds))]
                size = rng.uniform(spec.size[0], spec.size[1])
                c = np.array([[rng.uniform(0, layout.width), rng.uniform(0, layout.height)]])
                if kind == "cylinder":
                    cand, reach = Cylinder((float(c[0, 0]), float(c[0, 1])), float(size / 2)), size / 2
                else:
                    aspect = rng.uniform(0.5, 1.0)
                    cand = Box((float(c[0, 0]), float(c[0, 1])), (float(size), float(size * aspect)), float(rng.uniform(0, np.pi)))
                    reach = 0.5 * np.hypot(size, size * aspect)
                others = ObstacleSet.from_layout(dataclasses.replace(layout, obstacles=layout.obstacles + tuple(placed)),
                                                 include_border=False)
                if (inside_boundary(layout, c)[0] and not border_distance(c, border)[0] < reach + clearance
                        and not _spawn_distance(layout, c)[0] < reach + clearance
                        and not obstacle_distance(c, others, with_border=False)[0] < reach + clearance):
                    placed.append(cand)
                    break
            else:
                break
        if len(placed) == count:
            return placed
    return None


@pytest.mark.parametrize("index, count", [(0, 5), (1, 5), (2, 5), (3, 5), (3, 12)])
def test_batched_placement_places_what_drawing_one_at_a_time_places_and_leaves_the_generator_alike(index, count):
    """layout_random judges draws in batches and winds the generator back: the obstacles, and
    the generator's state after them (the spawn is drawn next), must be those of the plain rule."""
    layout = load_layout(index)
    for seed in range(12):
        fast, plain = np.random.default_rng(seed), np.random.default_rng(seed)
        try:
            got = layout.with_random_obstacles(fast, count).obstacles[len(layout.obstacles):]
        except LayoutError:
            got = None
        assert got == (None if (want := _placed_one_draw_at_a_time(layout, plain, count)) is None else tuple(want)), seed
        assert fast.bit_generator.state == plain.bit_generator.state, seed


def test_random_obstacles_in_a_small_round_border_of_a_big_arena_are_drawn_inside_its_reach():
    """Centres were drawn over the whole 50 x 50 m arena: 11 of 20 seeds found no room in a 2 m circle."""
    from pursuit_mj.layout_random import draw_region

    data = base_dict(arena={"width": 50.0, "height": 50.0}, boundary={"circle": {"center": [25.0, 25.0], "radius": 2.0}},
                     random_obstacles={"count": 5}, spawn={"pursuers": {"x": [24.0, 26.0], "y": [23.3, 23.6]},
                                                           "evaders": {"x": [24.0, 26.0], "y": [26.4, 26.7]}})
    layout = layout_from_dict(data, "round.yaml")
    assert draw_region(layout) == (23.0, 27.0, 23.0, 27.0)
    for seed in range(20):
        assert len(layout.with_random_obstacles(np.random.default_rng(seed)).obstacles) == 5
    for i in range(N_BUILTIN):  # the arena itself: every built-in layout draws the obstacles it always drew
        built_in = load_layout(i)
        assert draw_region(built_in) == (0.0, built_in.width, 0.0, built_in.height)


def test_layout_check_refuses_a_random_obstacle_count_that_fits_most_draws_but_not_all(tmp_path, capsys):
    """Seeds 0-19 all fitted, so it said valid; 2 in 100 episodes would then stop a run."""
    path = tmp_path / "twenty.yaml"
    path.write_text(yaml.safe_dump(base_dict(name="twenty", random_obstacles={"count": 20})))
    assert main(["layout", "check", str(path)]) == 2
    err = capsys.readouterr().err
    assert "no room for random obstacle" in err and "placement seeds 0-99: seeds 29, 35 found no room" in err


def test_a_draw_that_blocks_its_own_last_obstacles_starts_over_instead_of_failing_the_episode():
    layout = load_layout(3)
    for seed in (4, 37):  # with 10 obstacles, these draws once boxed in their 9th or 10th and stopped the run
        a = layout.with_random_obstacles(np.random.default_rng(seed), 10)
        assert a.n_random == 10 and a == layout.with_random_obstacles(np.random.default_rng(seed), 10)


def test_no_room_for_the_tasks_random_obstacle_count_names_the_task_key_not_the_file():
    env = PursuitEnv(default_config(layout=3, random_obstacles=30, fidelity="point"), seed=0)
    with pytest.raises(LayoutError, match=r"3_cluttered.yaml: no room for random obstacle \d+ of 30 .*; lower task.random_obstacles \(now 30\)$"):
        env.reset()


# a 1.6 m corridor whose three random cylinders, 0.3 m apart, close it for drones keeping 0.19 m
# in about half of the draws (passable keeping the default 0.1 m)
CORRIDOR = """
name: corridor
arena: {width: 1.6, height: 3.0}
obstacles: []
random_obstacles: {count: 3, kinds: [cylinder], size: [0.2, 0.4]}
spawn:
  pursuers: {x: [0.2, 1.4], y: [0.2, 0.6]}
  evaders: {x: [0.2, 1.4], y: [2.4, 2.8]}
"""
# 1.0 m wide: its one random cylinder (0.38-0.4 m, 0.3 m from both sides) always closes it at 0.19 m
NARROW = CORRIDOR.replace("width: 1.6", "width: 1.0").replace("x: [0.2, 1.4]", "x: [0.2, 0.8]").replace(
    "count: 3, kinds: [cylinder], size: [0.2, 0.4]", "count: 1, kinds: [cylinder], size: [0.38, 0.4]")


def _closed(layout, clearance: float) -> bool:
    """Whether walls or obstacles cut some spawn point off from the other team, for a drone keeping `clearance` (m)."""
    try:
        check_passages(layout, clearance)
    except LayoutError:
        return True
    return False


def test_random_obstacles_that_close_a_passage_for_the_tasks_obstacle_clearance_are_drawn_again():
    layout = layout_from_dict(yaml.safe_load(CORRIDOR), "corridor.yaml")
    env = PursuitEnv(default_config(obstacle_clearance=0.19, fidelity="point"), n_worlds=4, seed=0, layouts=[layout])
    closed_before = 0
    for episode in range(3):
        seeds = [episode_seed(0, w, episode) for w in range(4)]
        env.reset(seeds=seeds)
        for w, s in enumerate(seeds):
            assert env.world_layouts[w].n_random == 3
            check_passages(env.world_layouts[w], 0.19)  # every episode can be won
            plain = layout.with_random_obstacles(np.random.default_rng(s))  # the placement without the re-check
            closed_before += _closed(plain, 0.19)
            if not _closed(plain, 0.19):  # a passable first draw is kept: the same obstacles as without the check
                assert env.world_layouts[w] == plain
    assert closed_before > 0  # these episodes would have had their evaders cut off


def test_the_passage_recheck_is_seeded_and_keeps_a_passable_draw_and_the_generator_alike():
    layout = layout_from_dict(yaml.safe_load(CORRIDOR), "corridor.yaml")
    for seed in range(8):
        checked, plain = np.random.default_rng(seed), np.random.default_rng(seed)
        a = layout.with_random_obstacles(checked, passage_clearance=0.19)
        assert a == layout.with_random_obstacles(np.random.default_rng(seed), passage_clearance=0.19)
        check_passages(a, 0.19)
        b = layout.with_random_obstacles(plain)
        if not _closed(b, 0.19):
            assert a == b and checked.bit_generator.state == plain.bit_generator.state, seed


@pytest.mark.parametrize("clearance", [0.1, 0.15])
def test_random_obstacles_at_obstacle_clearances_their_separation_keeps_passable_are_those_without_a_check(clearance):
    """2 x obstacle_clearance within the random obstacles' 0.3 m separation: no re-check, the same
    obstacles as before it existed, and the same spawn (the episode's rng draws nothing more)."""
    layout = layout_from_dict(yaml.safe_load(CORRIDOR), "corridor.yaml")
    env = PursuitEnv(default_config(obstacle_clearance=clearance, fidelity="point"), n_worlds=4, seed=0, layouts=[layout])
    env.reset()
    for w in range(4):
        checked, plain = np.random.default_rng(episode_seed(0, w, 0)), np.random.default_rng(episode_seed(0, w, 0))
        want = layout.with_random_obstacles(plain)
        assert env.world_layouts[w] == want == layout.with_random_obstacles(checked, passage_clearance=clearance)
        assert checked.bit_generator.state == plain.bit_generator.state


def test_layout_show_draws_an_episodes_obstacles_with_the_tasks_obstacle_clearance(tmp_path):
    """Above 0.15 m the env draws closed placements again; the preview of an episode's seed must too."""
    from pursuit_mj.layout_preview import preview_layout

    layout = layout_from_dict(yaml.safe_load(CORRIDOR), "corridor.yaml")
    env = PursuitEnv(default_config(obstacle_clearance=0.19, fidelity="point"), n_worlds=4, seed=0, layouts=[layout])
    redrawn = 0
    for episode in range(3):
        seeds = [episode_seed(0, w, episode) for w in range(4)]
        env.reset(seeds=seeds)
        for w, s in enumerate(seeds):
            assert preview_layout(layout, s, passage_clearance=0.19) == env.world_layouts[w]
            redrawn += preview_layout(layout, s) != env.world_layouts[w]
    assert redrawn > 0  # without the task's clearance, some previews showed obstacles the episode never had
    path = tmp_path / "corridor.yaml"
    path.write_text(CORRIDOR)
    assert main(["layout", "show", str(path), "--seed", str(seeds[0]), "--obstacle-clearance", "0.19",
                 "-o", str(tmp_path / "c.png")]) == 0


def test_layout_show_names_its_obstacle_clearance_flag_when_no_placement_keeps_the_passages_open(tmp_path, capsys):
    path = tmp_path / "narrow.yaml"
    path.write_text(NARROW)
    assert main(["layout", "show", str(path), "-o", str(tmp_path / "a.png"), "--obstacle-clearance", "0.19"]) == 2
    err = capsys.readouterr().err
    assert "--obstacle-clearance 0.19" in err and "task.obstacle_clearance" not in err and len(err.strip().splitlines()) == 1, err
    assert main(["layout", "show", str(path), "-o", str(tmp_path / "b.png")]) == 0  # the default: the reference task's 0.1 m
    assert main(["layout", "show", str(path), "-o", str(tmp_path / "c.png"), "--obstacle-clearance", "-0.1"]) == 2
    assert "--obstacle-clearance: must be >= 0, got -0.1" in capsys.readouterr().err


def test_random_obstacles_that_always_close_a_passage_are_refused_naming_the_settings():
    layout = layout_from_dict(yaml.safe_load(NARROW), "narrow.yaml")
    env = PursuitEnv(default_config(obstacle_clearance=0.19, fidelity="point"), seed=0, layouts=[layout])
    with pytest.raises(LayoutError, match=r"narrow.yaml: .*task.obstacle_clearance.* 0.19 m.*; lower task.obstacle_clearance, "
                                          r"random_obstacles.count or random_obstacles.size in narrow.yaml"):
        env.reset()
    PursuitEnv(default_config(obstacle_clearance=0.15, fidelity="point"), seed=0, layouts=[layout]).reset()


def _outline(layout_with_one_obstacle) -> np.ndarray:
    """Points (K, 2) on the boundary of the layout's only obstacle."""
    grid = np.stack(np.meshgrid(np.linspace(0, 3.6, 181), np.linspace(0, 5.0, 251)), -1).reshape(-1, 2)
    d = obstacle_distance(grid, ObstacleSet.from_layout(layout_with_one_obstacle, include_border=False), with_border=False)
    return grid[np.abs(d) < 0.02]


def test_no_room_for_random_obstacles_is_refused():
    layout = layout_from_dict(base_dict(random_obstacles={"count": 40, "size": [0.5, 0.6]}), "crowded.yaml")
    with pytest.raises(LayoutError, match=r"crowded.yaml: no room for random obstacle \d+ of 40"):
        layout.with_random_obstacles(np.random.default_rng(0))


def _components_by_flood_fill(free: np.ndarray) -> np.ndarray:
    """The plain reference: a breadth-first flood fill from each unlabelled free cell (8-connected)."""
    from collections import deque

    label = np.full(free.shape, -1)
    for start in zip(*np.nonzero(free)):
        if label[start] >= 0:
            continue
        label[start] = k = label.max() + 1
        queue = deque([start])
        while queue:
            i, j = queue.popleft()
            for a in range(max(i - 1, 0), min(i + 2, free.shape[0])):
                for b in range(max(j - 1, 0), min(j + 2, free.shape[1])):
                    if free[a, b] and label[a, b] < 0:
                        label[a, b] = k
                        queue.append((a, b))
    return label


def test_grid_components_split_the_free_cells_as_a_flood_fill_does():
    rng = np.random.default_rng(0)
    snake = np.zeros((21, 21), bool)  # one winding corridor, against the order of the cell indices
    snake[::4] = True
    for r in range(0, 17, 4):
        snake[r + 1:r + 4, 20 if r % 8 == 0 else 0] = True
    grids = [rng.random((int(rng.integers(1, 25)), int(rng.integers(1, 25)))) < rng.uniform(0.2, 0.8) for _ in range(100)]
    for free in grids + [snake, snake.T[::-1], np.zeros((3, 4), bool), np.ones((3, 4), bool)]:
        got, want = grid_components(free), _components_by_flood_fill(free)
        assert ((got < 0) == ~free).all() and ((want < 0) == ~free).all()
        pairs = set(zip(got[free].tolist(), want[free].tolist()))  # the same partition: labels map one to one
        assert len(pairs) == len({g for g, _ in pairs}) == len({w for _, w in pairs})
    assert len(np.unique(grid_components(snake)[snake])) == 1


def _free_by_brute_force(layout, xs, ys, clearance):
    grid = np.stack(np.meshgrid(xs, ys, indexing="ij"), -1)
    flat = grid.reshape(-1, 2)
    return (inside_boundary(layout, flat) & (obstacle_distance(flat, ObstacleSet.from_layout(layout)) >= clearance)).reshape(grid.shape[:2])


def test_the_reachability_grids_free_cells_are_the_point_by_point_tests_cell_for_cell():
    from pursuit_mj.layout_check import free_cells, grid_step

    layouts = [load_layout(i) for i in range(4)] + [layout_from_dict(d, "x.yaml") for d in (POLYGON, CIRCLE)]
    layouts += [load_layout(3).with_random_obstacles(np.random.default_rng(k), 8) for k in range(2)]
    for layout in layouts:
        for clearance in (0.1, 0.25):
            step = grid_step(layout, clearance)
            xs, ys = np.arange(step / 2, layout.width, step), np.arange(step / 2, layout.height, step)
            assert np.array_equal(free_cells(layout, xs, ys, clearance), _free_by_brute_force(layout, xs, ys, clearance))


@pytest.mark.parametrize("side", [30.0, 50.0])
def test_a_thin_diagonal_wall_cutting_a_big_arena_in_two_is_refused(side):
    """Above about 42 m the grid's diagonal step hopped over the wall's 0.21 m band, and the layout was accepted."""
    e = 0.01
    data = base_dict(arena={"width": side, "height": side},
                     obstacles=[{"wall": {"from": [e, e], "to": [side - e, side - e], "thickness": 0.01}}],
                     spawn={"pursuers": {"x": [side - 3, side - 1], "y": [1, 3]}, "evaders": {"x": [1, 3], "y": [side - 3, side - 1]}})
    with pytest.raises(LayoutError, match="cannot be reached from the pursuers'"):
        layout_from_dict(data, "big.yaml")


def test_an_obstacle_too_thin_for_any_reachability_grid_is_refused_naming_it():
    from pursuit_mj.layout_check import spawn_components

    data = base_dict(arena={"width": 50.0, "height": 50.0}, obstacles=[{"wall": {"from": [1, 25], "to": [20, 25], "thickness": 0.001}}],
                     spawn={"pursuers": {"x": [30, 32], "y": [1, 3]}, "evaders": {"x": [30, 32], "y": [45, 47]}})
    layout = layout_from_dict(data, "thin.yaml")  # at the 0.1 m clearance of the check a grid of 354 cells a side does
    with pytest.raises(LayoutError, match=r"thin.yaml: its 0.001 m thin obstacle, with 0 m of clearance, needs a reachability grid"):
        spawn_components(layout, clearance=0.0)


# ----------------------------------------------------------------------------- malformed and impossible


@pytest.mark.parametrize(
    "data, message",
    [
        ({k: v for k, v in base_dict().items() if k != "arena"}, r"bad.yaml: missing key 'arena'"),
        (base_dict(arena={"width": 3.6}), r"arena: missing key 'height'"),
        (base_dict(obstacles=[{"sphere": {"center": [1, 1], "radius": 0.2}}]), r"obstacles\[0\]: unknown obstacle kind 'sphere'"),
        (base_dict(obstacles=[{"box": {"center": [1, 1]}}]), r"obstacles\[0\] \(box\): missing key 'size'"),
        (base_dict(obstacles=[{"box": {"center": [1, "a"], "size": [1, 1]}}]), r"obstacles\[0\] \(box\).center: expected two finite numbers"),
        (base_dict(obstacles=[{"box": {"center": [1.8, 2.5], "size": [0.6, 0.2], "yaw": 45}}]),
         r"bad.yaml: obstacles\[0\] \(box\).yaw: 45 is beyond \+-2 pi: yaw is in radians, not degrees"),
        (base_dict(obstacles=[{"cylinder": {"center": [1, 1], "radius": -0.2}}]), r"obstacles\[0\] \(cylinder\).radius: must be > 0, got -0.2"),
        (base_dict(obstacles=[{"wall": {"from": [1, 1], "to": [1, 1]}}]), r"obstacles\[0\] \(wall\): 'from' and 'to' are the same point"),
        (base_dict(arena={"width": "wide", "height": 5}), r"arena.width: expected a number, got 'wide'"),
        (base_dict(arena={"width": float("nan"), "height": 5}), r"arena.width: expected a number, got nan"),
        (base_dict(color="red"), r"unknown key 'color'"),
        (base_dict(name=None), r"bad.yaml: name None: expected text"),
        (base_dict(name=[1, 2]), r"bad.yaml: name \[1, 2\]: expected text"),
        (base_dict(obstacles={}), r"bad.yaml: obstacles: expected a list, got \{\}"),
        (base_dict(obstacles=0), r"bad.yaml: obstacles: expected a list, got 0"),
        (base_dict(spawn={"pursuers": {"x": [3, 1], "y": [0.2, 0.8]}, "evaders": SPAWN["evaders"]}), r"spawn.pursuers: ranges must be \[low, high\]"),
        (base_dict(random_obstacles={"count": 2, "kinds": ["pyramid"]}), r"random_obstacles.kinds: unknown kind 'pyramid'"),
        (base_dict(random_obstacles={"count": -1}), r"random_obstacles.count: expected an integer >= 0, got -1"),
        # the physics reserves a geom per random obstacle in every world: 10**7 hung PursuitEnv(), as task.random_obstacles would not
        (base_dict(random_obstacles={"count": 10**7}), r"bad.yaml: random_obstacles.count: 10000000 is more than 64, the most .* task.random_obstacles"),
        (base_dict(boundary={"polygon": [[0, 0], [1, 1]]}), r"boundary.polygon: expected at least 3"),
        (base_dict(boundary="triangle"), r"boundary: expected 'rectangle'"),
    ],
)
def test_malformed_layouts_are_refused_naming_the_entry(data, message, tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(LayoutError, match=message):
        load_layout(path)


@pytest.mark.parametrize(
    "data, message",
    [
        # a fixed start point written as one number was told 'expected [x, y], got 1.8': the shape of a
        # point, where a spawn range is [low, high]
        (base_dict(spawn={"pursuers": SPAWN["pursuers"], "evaders": {"x": 1.8, "y": [4.5, 4.5]}}),
         r"bad.yaml: spawn.evaders.x: expected a range \[low, high\] \(m; \[1.8, 1.8\] for a fixed start\), got 1.8$"),
        (base_dict(spawn={"pursuers": {"x": [0.2, 3.4], "y": [0.2, 0.5, 0.8]}, "evaders": SPAWN["evaders"]}),
         r"bad.yaml: spawn.pursuers.y: expected a range \[low, high\] \(m\), got \[0.2, 0.5, 0.8\]$"),
        (base_dict(random_obstacles={"count": 2, "size": 0.3}),
         r"bad.yaml: random_obstacles.size: expected a range \[min, max\] \(m; \[0.3, 0.3\] for one size\), got 0.3$"),
        (base_dict(obstacles=[{"cylinder": {"center": 1.0, "radius": 0.2}}]), r"center: expected \[x, y\], got 1.0$"),
    ],
)
def test_a_range_written_as_another_shape_is_refused_as_a_range(data, message, tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(LayoutError, match=message):
        load_layout(path)


def test_a_random_obstacle_count_written_as_a_whole_float_is_a_count(tmp_path):
    """random_obstacles.count 3.0 (or 3e0) was refused 'expected an integer >= 0, got 3.0', where the
    task's counts (random_obstacles, n_pursuers, max_steps) take a whole number written so."""
    path = tmp_path / "floats.yaml"
    for written in ("3.0", "3e0"):
        path.write_text(yaml.safe_dump(base_dict(random_obstacles={"count": 0})).replace("count: 0", f"count: {written}"))
        count = load_layout(path).random_obstacles.count
        assert count == 3 and type(count) is int
    path.write_text(yaml.safe_dump(base_dict(random_obstacles={"count": 2.5})))
    with pytest.raises(LayoutError, match=r"random_obstacles.count: expected an integer >= 0, got 2.5"):
        load_layout(path)


@pytest.mark.parametrize(
    "data, message",
    [
        (base_dict(obstacles=[{"box": {"center": [1.8, 0.5], "size": [3.6, 1.0]}}]), r"spawn.pursuers .* has no free point"),
        (base_dict(obstacles=[{"cylinder": {"center": [3.5, 2.5], "radius": 0.3}}]), r"obstacles\[0\] \(cylinder centre \[3.5, 2.5\] radius 0.3\) lies \(partly\) outside the 3.6 x 5.0 m arena"),
        (base_dict(obstacles=[{"wall": {"from": [-0.5, 2.5], "to": [1.0, 2.5]}}]), r"obstacles\[0\] \(wall from \[-0.5, 2.5\] to \[1.0, 2.5\]\) lies \(partly\) outside"),
        (base_dict(spawn={"pursuers": {"x": [0.2, 4.0], "y": [0.2, 0.8]}, "evaders": SPAWN["evaders"]}), r"spawn.pursuers .* leaves the arena"),
        (dict(CIRCLE, boundary={"circle": {"center": [2.0, 2.0], "radius": 2.5}}), r"boundary circle .* leaves the arena"),
        (dict(CIRCLE, spawn={"pursuers": {"x": [0.0, 0.4], "y": [0.0, 0.4]}, "evaders": CIRCLE["spawn"]["evaders"]}),
         r"spawn.pursuers x=\[0.0, 0.4\] y=\[0.0, 0.4\] lies outside the circle boundary"),
        (dict(CIRCLE, obstacles=[{"cylinder": {"center": [0.2, 0.2], "radius": 0.1}}]), r"obstacles\[0\] \(cylinder .*\) has its centre outside the circle boundary"),
        # centre outside, but the rim point the check used to take for the centre inside
        (dict(CIRCLE, obstacles=[{"cylinder": {"center": [0.2, 2.75], "radius": 0.15}}]), r"obstacles\[0\] \(cylinder .*\) has its centre outside the circle boundary"),
        (base_dict(obstacles=[{"wall": {"from": [0.0, 2.5], "to": [3.6, 2.5]}}]), r"evaders' spawn region cannot be reached from the pursuers'"),
        (base_dict(obstacles=[{"wall": {"from": [0.0, 2.5], "to": [3.45, 2.5]}}]), r"cannot be reached"),  # a 0.15 m gap: too narrow
        # a closed room in a corner of the evaders' band: an evader spawned in it could never be caught
        (base_dict(obstacles=[{"wall": {"from": [0.0, 3.8], "to": [1.2, 3.8]}}, {"wall": {"from": [1.2, 3.8], "to": [1.2, 5.0]}}]),
         r"spawn.evaders x=\[0.2, 3.4\] y=\[4.2, 4.8\] reaches into a pocket cut off from the other team .* at \[0.2, 4.2\]"),
        (base_dict(obstacles=[{"wall": {"from": [2.4, 0.0], "to": [2.4, 1.2]}}, {"wall": {"from": [2.4, 1.2], "to": [3.6, 1.2]}}]),
         r"spawn.pursuers .* reaches into a pocket cut off from the other team"),
        (base_dict(boundary={"polygon": [[0, 0], [3.6, 0], [1, 5], [3.6, 4]]}), r"boundary.polygon: edge \[3.6, 0.0\] -> \[1.0, 5.0\] crosses edge"),
        (base_dict(boundary={"polygon": [[0, 0], [3.6, 5], [3.6, 0], [0, 5]]}), r"must not cross itself"),
        (base_dict(boundary={"polygon": [[0, 0], [3.6, 0], [3.6, 5], [0, 5], [3.6, 0]]}), r"point 4 \[3.6, 0.0\] repeats point 1"),
        # a notch whose sides come back along the top edge: the border runs over itself from x 2.0 to 2.5, and the
        # walls outside its edges stood 5 cm into the flyable region
        (base_dict(boundary={"polygon": [[0, 0], [3.6, 0], [3.6, 5], [2.0, 5], [2.0, 3], [2.5, 3], [2.5, 5], [0, 5]]}),
         r"boundary.polygon: point 6 \[2.5, 5.0\] lies on edge \[3.6, 5.0\] -> \[2.0, 5.0\]: the border must not touch itself"),
        (base_dict(boundary={"polygon": [[0, 0], [3.6, 0], [3.6, 5], [3.6, 2], [0, 5]]}), r"at \[3.6, 5.0\] the border turns straight back"),
        (base_dict(arena={"width": 1e6, "height": 5.0}), r"arena.width: 1e\+06 m is beyond the 50 m"),
        # a slit 4 cm wide cut into the border (a thin wall drawn as a notch): the 5 cm wall outside each
        # side stood 1 cm into the flyable region on the other, where the 2D geometry saw free space
        (base_dict(boundary={"polygon": [[0, 0], [3.6, 0], [3.6, 5], [0, 5], [0, 2.52], [2.6, 2.52], [2.6, 2.48], [0, 2.48]]}),
         r"boundary.polygon: outside edge \[0.0, 2.52\] -> \[2.6, 2.52\] the border comes back within 0.05 m \(edge "
         r"\[2.6, 2.48\] -> \[0.0, 2.48\]\)"),
        # an inward spike sharper than a right angle: box walls outside its edges would stand in the arena
        (base_dict(boundary={"polygon": [[0, 0], [3.6, 0], [3.6, 5], [2.8, 5], [1.8, 3.5], [0.8, 5], [0, 5]]}),
         r"boundary.polygon: at \[1.8, 3.5\] the border turns into the arena at an inside angle of 293 deg, over 270"),
        # in the corner an octagon cuts off: it said "spawn region inside an obstacle?"
        (base_dict(boundary={"polygon": [[0.6, 0], [3.0, 0], [3.6, 0.6], [3.6, 4.4], [3.0, 5], [0.6, 5], [0, 4.4], [0, 0.6]]},
                   spawn={"pursuers": {"x": [0.0, 0.25], "y": [0.0, 0.25]}, "evaders": SPAWN["evaders"]}),
         r"spawn.pursuers x=\[0.0, 0.25\] y=\[0.0, 0.25\] lies outside the polygon boundary"),
    ],
)
def test_impossible_layouts_are_refused_naming_the_entry(data, message):
    with pytest.raises(LayoutError, match=message):
        layout_from_dict(data, "impossible.yaml")


@pytest.mark.parametrize("kind", ["box", "cylinder"])
def test_an_obstacle_centred_inside_a_round_border_may_reach_through_it_whatever_its_kind(kind):
    # a cylinder was refused as "centre outside" when one point of its rim was: a box there was accepted
    body = {"center": [3.5, 1.2], **({"radius": 0.3} if kind == "cylinder" else {"size": [0.6, 0.6]})}
    layout_from_dict(dict(CIRCLE, obstacles=[{kind: body}]), "round.yaml")


def test_a_passage_just_wide_enough_is_accepted():
    layout_from_dict(base_dict(obstacles=[{"wall": {"from": [0.0, 2.5], "to": [3.3, 2.5]}}]), "gap.yaml")  # 0.3 m minus the wall's half-thickness


def test_a_passage_too_narrow_for_the_tasks_obstacle_clearance_is_refused_naming_the_key(tmp_path):
    path = tmp_path / "gap.yaml"
    path.write_text(yaml.safe_dump(base_dict(obstacles=[{"wall": {"from": [0.0, 2.5], "to": [3.35, 2.5]}}])))  # a 0.25 m gap
    PursuitEnv(default_config(layout=str(path), fidelity="point"))  # passable keeping the default 0.1 m
    with pytest.raises(LayoutError, match=r"gap.yaml: the evaders' spawn region cannot be reached .* \(a passage needs 0.3 m at task.obstacle_clearance 0.15 m, found on a grid of 5 cm\)"):
        PursuitEnv(default_config(layout=str(path), fidelity="point", obstacle_clearance=0.15))


def test_a_spawn_strip_thinner_than_the_reachability_grid_is_accepted_and_spawns_on_it(tmp_path):
    strip = {"pursuers": {"x": [1.81, 1.82], "y": [0.2, 1.4]}, "evaders": SPAWN["evaders"]}  # 1 cm wide, 5 cm grid
    path = tmp_path / "strip.yaml"
    path.write_text(yaml.safe_dump(base_dict(spawn=strip)))
    env = PursuitEnv(default_config(layout=str(path), fidelity="point"), seed=0)
    env.reset()
    x = env.snapshot(0).pursuer_pos[:, 0]
    assert ((x >= 1.81 - 1e-6) & (x <= 1.82 + 1e-6)).all()


def test_a_spawn_point_fixes_the_start_of_a_drone_in_every_episode(tmp_path):
    """A spawn region with low == high in x and y is a point: a user fixes a start position. It
    was refused ('ranges must be [low, high] with low < high'); now the evader starts there in
    every episode of a real compiled scene, random obstacles and all, and the episode runs."""
    point = {"pursuers": SPAWN["pursuers"], "evaders": {"x": [1.8, 1.8], "y": [4.5, 4.5]}}
    path = tmp_path / "fixed.yaml"
    path.write_text(yaml.safe_dump(base_dict(spawn=point)))
    layout = load_layout(path)
    assert layout.spawn_evaders.x == (1.8, 1.8) and round_trip(layout, tmp_path / "again.yaml").spawn_evaders.y == (4.5, 4.5)
    config = default_config(layout=str(path), fidelity="point", max_steps=20)
    env = PursuitEnv(config, n_worlds=3, seed=4, auto_reset=False)
    starts = []
    for episode in range(3):
        env.reset() if episode == 0 else env.reset_worlds([0, 1, 2])
        starts.append(np.stack([env.snapshot(w).evader_pos[0, :2] for w in range(3)]))
        pursuers = np.stack([env.snapshot(w).pursuer_pos[:, :2] for w in range(3)])
        assert len({tuple(p.round(6)) for p in pursuers.reshape(-1, 2)}) > 3  # the pursuers' region still draws
        while not env.done.all():
            env.step(np.zeros((3, config.n_pursuers, 2)))
    np.testing.assert_allclose(np.stack(starts), np.broadcast_to([1.8, 4.5], (3, 3, 2)), atol=2e-3)
    assert env.episode.tolist() == [2, 2, 2]


def test_a_spawn_point_holds_one_drone_and_keeps_the_layout_checks(tmp_path):
    """A point holds one drone: a team of several is refused saying they need room 0.4 m apart;
    one drone there is accepted; a point inside an obstacle or in a closed pocket is refused as
    a region there is."""
    point = {"x": [0.6, 0.6], "y": [0.5, 0.5]}
    path = tmp_path / "point.yaml"
    path.write_text(yaml.safe_dump(base_dict(spawn={"pursuers": point, "evaders": SPAWN["evaders"]})))
    with pytest.raises(LayoutError, match=r"n_pursuers=3: spawn.pursuers of .*point.yaml is a single point \(x=0.6, y=0.5\), "
                                          r"which holds one drone; 3 pursuers need room 0.4 m apart"):
        PursuitEnv(default_config(layout=str(path), fidelity="point"))
    env = PursuitEnv(default_config(layout=str(path), fidelity="point", n_pursuers=1), seed=1)
    env.reset()
    np.testing.assert_allclose(env.snapshot(0).pursuer_pos[0, :2], [0.6, 0.5], atol=2e-3)
    inside = base_dict(spawn={"pursuers": point, "evaders": SPAWN["evaders"]},
                       obstacles=[{"cylinder": {"center": [0.6, 0.5], "radius": 0.2}}])
    with pytest.raises(LayoutError, match=r"spawn.pursuers x=\[0.6, 0.6\] y=\[0.5, 0.5\] has no free point"):
        layout_from_dict(inside, "inside.yaml")
    pocket = base_dict(spawn={"pursuers": point, "evaders": SPAWN["evaders"]},
                       obstacles=[{"wall": {"from": [0.0, 1.2], "to": [1.2, 1.2]}}, {"wall": {"from": [1.2, 0.0], "to": [1.2, 1.2]}}])
    with pytest.raises(LayoutError, match=r"pocket.yaml: the evaders' spawn region cannot be reached from the pursuers'"):
        layout_from_dict(pocket, "pocket.yaml")


def test_duplicate_keys_and_non_text_files_are_refused(tmp_path):
    path = tmp_path / "twice.yaml"
    path.write_text(yaml.safe_dump(base_dict()) + "name: again\n")
    with pytest.raises(LayoutError, match=r"twice.yaml: not valid YAML, line \d+, column 1: key 'name' given twice \(first on line \d+\)"):
        load_layout(path)
    picture = tmp_path / "layout.png"
    picture.write_bytes(b"\x89PNG\r\n\x1a\n\x00\xff")
    with pytest.raises(ValueError, match=r"layout.png: not a text \(YAML\) file"):
        load_layout(picture)


def test_invalid_yaml_is_refused_with_the_file_name(tmp_path):
    path = tmp_path / "broken.yaml"
    path.write_text("arena: {width: 3.6, height: [\n")
    with pytest.raises(LayoutError, match=r"broken.yaml: not valid YAML, line \d+, column \d+: "):
        load_layout(path)


@pytest.mark.parametrize("text", ["", "# a comment, nothing else\n", "---\n"])
def test_an_empty_layout_file_is_refused_as_empty(text, tmp_path):
    path = tmp_path / "empty.yaml"
    path.write_text(text)
    with pytest.raises(LayoutError, match=r"empty.yaml: the file holds no layout; a layout sets at least arena and spawn"):
        load_layout(path)


# ----------------------------------------------------------------------------- CLI


def test_layout_new_writes_a_valid_file_and_show_draws_it(tmp_path, capsys):
    out = tmp_path / "new.yaml"
    code = main(["layout", "new", str(out), "--border", "circle", "--width", "4", "--height", "4", "--cylinder", "2", "2", "0.3",
                 "--box", "3.0", "2.0", "0.3", "0.5", "0.4", "--wall", "0.7", "1.5", "0.7", "2.5", "--random", "2", "--seed", "5",
                 "--episode-obstacles", "2"])
    assert code == 0 and "wrote" in capsys.readouterr().out
    layout = load_layout(out)
    assert layout.boundary.kind == "circle" and len(layout.obstacles) == 3 + 2 and layout.random_obstacles.count == 2
    png = tmp_path / "new.png"
    assert main(["layout", "show", str(out), "-o", str(png), "--seed", "1"]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000
    assert main(["layout", "check", str(out)]) == 0
    report = capsys.readouterr().out
    assert "valid" in report and "compiles" in report
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []  # no temp files left


def test_layout_new_with_polygon_points_sizes_the_arena_to_them_unless_told(tmp_path, capsys):
    out = tmp_path / "pentagon.yaml"
    assert main(["layout", "new", str(out), "--border", "polygon", "--points", "0,0", "5,0", "5,4", "2.5,6", "0,4"]) == 0
    layout = load_layout(out)
    assert (layout.width, layout.height) == (5.0, 6.0)
    assert main(["layout", "new", str(tmp_path / "x.yaml"), "--border", "polygon", "--points", "0,0", "5,0", "5,5", "0,5",
                 "--width", "4"]) == 2
    err = capsys.readouterr().err
    assert "lies outside the 4.0 x 5.0 m arena" in err and "--width" in err, err


def test_layout_new_default_polygon_and_seeded_random_obstacles_are_reproducible(tmp_path):
    a, b = tmp_path / "a.yaml", tmp_path / "b.yaml"
    for path in (a, b):
        assert main(["layout", "new", str(path), "--border", "polygon", "--random", "3", "--seed", "9", "--name", "same"]) == 0
    assert a.read_text() == b.read_text()
    assert load_layout(a).boundary.kind == "polygon"


@pytest.mark.parametrize(
    "argv, message",
    [
        (["layout", "new", "{out}", "--box", "1", "2", "3"], "--box: expected CX CY SX SY [YAW], got 3 numbers"),
        (["layout", "new", "{out}", "--box", "5", "2", "0.3", "0.3"], "the 1st --box 5 2 0.3 0.3 (box centre [5.0, 2.0] size [0.3, 0.3]) lies (partly) outside"),
        # the file lists boxes, then cylinders, then walls: obstacles[0] was the third flag typed
        (["layout", "new", "{out}", "--cylinder", "1", "2", "0.3", "--wall", "1", "3", "2", "3", "--box", "5", "2", "0.3", "0.3"],
         "the 1st --box 5 2 0.3 0.3 (box centre"),
        (["layout", "new", "{out}", "--cylinder", "1", "2", "0.3", "--cylinder", "2", "1", "0"], "the 2nd --cylinder 2 1 0 (cylinder).radius: must be > 0"),
        (["layout", "new", "{out}", "--border", "circle", "--radius", "-1"], "--radius: must be a number > 0, got -1.0"),
        (["layout", "new", "{out}", "--border", "polygon", "--points", "0,0", "1,x"], "--points: '1,x' is not X,Y"),
        (["layout", "new", "{out}", "--width", "-1"], "--width: must be a number > 0, got -1.0"),
        (["layout", "new", "{out}", "--episode-obstacles", "60"], "no room for random obstacle"),
        (["layout", "new", "{out}", "--radius", "1"], "--center/--radius: only used with --border circle"),
        (["layout", "show", "7"], "layout 7: no built-in layout with this index"),
        (["layout", "show", "\u00b2"], "layout '\u00b2': no such file"),  # a digit to str.isdigit, not to int()
        (["layout", "check", ""], "layout '': empty; expected a built-in index 0-3 or a file path"),
        (["layout", "new", "{out}.png"], ".png: expected a .yaml file name"),
        (["layout", "show", "0", "-o", "{out}"], "expected a .png file name"),
        (["layout", "show", "0", "--count", "65", "-o", "{out}.png"], "layout show: error: --count: 65 is out of range (0 to 64"),
        # no task takes it (it was drawn): spawned drones would collide at once
        (["layout", "show", "3", "--count", "0", "--obstacle-clearance", "0.29", "-o", "{out}.png"],
         "layout show: error: --obstacle-clearance 0.29: 0.29 m is not below the 0.2 m that drones spawn from walls"),
        (["layout", "show", "0", "--count", "64", "-o", "{out}.png"], "layout show: error: --count 64: "),  # no room
        (["layout", "show", "0", "--count", "2", "--no-random", "-o", "{out}.png"], "--count 2: draws random obstacles, which --no-random leaves out"),
        (["layout", "check", "missing.yaml"], "layout 'missing.yaml': no such file"),
        (["layout", "new", "{out}", "--width", "10", "--height", "1.2"],  # the default spawn bands, which it had not said how to move
         "move the regions apart (with --spawn-pursuers and --spawn-evaders, or a longer arena)"),
        (["layout", "new", "{out}", "--spawn-pursuers", "0.2", "3.4", "0.2", "2.5", "--spawn-evaders", "0.2", "3.4", "2.6", "4.8"],
         "move the regions apart (with --spawn-pursuers and --spawn-evaders)"),  # a longer arena would not move them
        (["layout", "new", "{out}", "--width", "0.7", "--height", "3", "--episode-obstacles", "0"],
         "cannot reliably hold 3 pursuers 0.4 m apart"),  # the file would be refused by every command
        (["layout", "new", "{out}", "--spawn-pursuers", "1", "2.6", "2", "3", "--spawn-evaders", "1", "2.6", "2", "3"],
         "spawn regions overlap"),
        (["layout", "new", "{out}", "--name", "../x"], "name '../x': must be a plain label"),
        (["layout", "new", "{out}", "--name", ""], "name '': must be a plain label"),
        (["layout", "new", "{out}", "--name", ".."], "name '..': must be a plain label"),
        (["layout", "new", "{out}", "--random", "60"], "no room for random obstacle"),
        # above the file format's bound: the error named the file key random_obstacles.count
        (["layout", "new", "{out}", "--episode-obstacles", "100"], "--episode-obstacles: 100 is out of range (0 to 64)"),
        # --random places fixed obstacles: the error named random_obstacles.count, the per-episode ones
        (["layout", "new", "{out}", "--random", "100"], "--random: 100 is out of range (0 to 64)"),
    ],
)
def test_layout_cli_bad_input_exits_2_with_one_line(argv, message, tmp_path, capsys):
    argv = [a.replace("{out}", str(tmp_path / "out.yaml")) for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err, err
    assert not (tmp_path / "out.yaml").exists()


@pytest.mark.parametrize("argv, hint", [(["--random", "60"], "lower --random or --obstacle-size"),
                                        (["--episode-obstacles", "60"], "lower --episode-obstacles or --obstacle-size")])
def test_layout_new_without_room_names_the_flag_to_lower_once(argv, hint, tmp_path, capsys):
    assert main(["layout", "new", str(tmp_path / "out.yaml")] + argv) == 2
    err = capsys.readouterr().err
    assert hint in err and "random_obstacles.count" not in err and err.count("lower") == 1, err


def test_layout_new_without_room_counts_its_tries_not_placements(tmp_path, capsys):
    """'no room for random obstacle 19 of 50 in 10 placements': the 10 are tries, each placing
    every obstacle anew, not placements of the one that found no room."""
    assert main(["layout", "new", str(tmp_path / "out.yaml"), "--random", "50"]) == 2
    err = capsys.readouterr().err
    assert re.search(r"no room for random obstacle \d+ of 50 in 10 tries at placing all 50 \(sizes", err), err


def test_layout_new_into_a_folder_says_so_rather_than_asking_for_force(tmp_path, capsys):
    for argv in ([str(tmp_path)], [str(tmp_path), "--force"]):
        assert main(["layout", "new"] + argv) == 2
        err = capsys.readouterr().err
        assert f"OUT path {tmp_path}: is a folder, expected a file name" in err and "--force" not in err, err


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs Linux /proc")
def test_layout_show_into_a_folder_that_takes_no_new_files_is_one_line(capsys):
    """/proc passes the access check as root, but no file can be made there: a FileNotFoundError
    traceback from the temp file beside the PNG."""
    assert main(["layout", "show", "0", "-o", "/proc/x.png"]) == 2
    err = capsys.readouterr().err
    assert "/proc/x.png" in err and "Traceback" not in err and len(err.strip().splitlines()) == 1, err


def test_layout_new_refuses_to_overwrite_without_force(tmp_path, capsys):
    out = tmp_path / "x.yaml"
    out.write_text("keep me")
    assert main(["layout", "new", str(out)]) == 2
    assert out.read_text() == "keep me" and "--force" in capsys.readouterr().err
    assert main(["layout", "new", str(out), "--force"]) == 0
    assert load_layout(out).name == "x"


def test_layout_check_says_valid_only_after_every_check_and_checks_the_team_size(tmp_path, capsys):
    crowded = tmp_path / "crowded.yaml"
    crowded.write_text(yaml.safe_dump(base_dict(random_obstacles={"count": 60})))
    assert main(["layout", "check", str(crowded)]) == 2
    captured = capsys.readouterr()
    assert "valid" not in captured.out and "no room for random obstacle" in captured.err
    assert main(["layout", "check", "0", "--pursuers", "16"]) == 2
    assert "cannot reliably hold 16 pursuers 0.4 m apart" in capsys.readouterr().err
    assert main(["layout", "check", "0", "--pursuers", "5", "--evaders", "2"]) == 0
    out = capsys.readouterr().out
    assert "room for 5 pursuers and 2 evader(s)" in out and "(point, 5+2 drones, seed 0): compiles" in out


@pytest.mark.parametrize("team, message", [(["--pursuers", "17"], "--pursuers: 17 is out of range (1 to 16, the task's n_pursuers)"),
                                           (["--evaders", "9"], "--evaders: 9 is out of range (1 to 8, the task's n_evaders)"),
                                           (["--pursuers", "0"], "--pursuers: 0 is out of range (1 to 16")])
def test_layout_commands_refuse_a_team_no_task_can_have(team, message, tmp_path, capsys):
    """A 20 x 20 m layout has room for 40 pursuers, but every task refuses more than 16: check said 'valid'."""
    big = tmp_path / "big.yaml"
    assert main(["layout", "new", str(big), "--width", "20", "--height", "20", "--spawn-pursuers", "1", "19", "1", "5",
                 "--spawn-evaders", "1", "19", "15", "19"]) == 0
    capsys.readouterr()
    for argv in (["layout", "check", str(big)], ["layout", "new", str(tmp_path / "other.yaml"), "--width", "20", "--height", "20"]):
        assert main(argv + team) == 2
        captured = capsys.readouterr()
        assert message in captured.err and "valid" not in captured.out, captured
    assert not (tmp_path / "other.yaml").exists()


def test_the_example_in_layout_new_help_works(tmp_path, capsys):
    from pursuit_cli import build_parser

    parser = build_parser()
    new = parser._subparsers._group_actions[0].choices["layout"]._subparsers._group_actions[0].choices["new"]
    example = new.epilog.split("example: pursuit-mj ", 1)[1].split()
    example[2] = str(tmp_path / "arena.yaml")
    assert main(example) == 0, capsys.readouterr().err


def test_what_random_obstacles_size_measures_is_said_where_it_is_set(capsys):
    """A cylinder's diameter or a box's longer side, as placement draws it (checked in
    test_random_obstacles_are_seeded_and_keep_off_spawn_regions_and_each_other); it was said nowhere."""
    with pytest.raises(SystemExit):
        main(["layout", "new", "--help"])
    help_text = " ".join(capsys.readouterr().out.split())
    assert "a cylinder's diameter, a box's longer side" in help_text
    design = " ".join((Path(__file__).parents[1] / "docs" / "DESIGN.md").read_text().split())
    assert "a cylinder's diameter, or a box's longer side" in design


def test_layout_new_puts_default_spawn_bands_inside_a_polygon(tmp_path):
    from pursuit_mj.geometry import inside_polygon

    out = tmp_path / "house.yaml"
    corners = [[0, 0], [4, 0], [4, 5], [2, 6], [0, 5]]  # a roof above y = 5
    assert main(["layout", "new", str(out), "--border", "polygon", "--points", *(f"{x},{y}" for x, y in corners),
                 "--width", "4", "--height", "6"]) == 0
    layout = load_layout(out)
    for region in (layout.spawn_pursuers, layout.spawn_evaders):
        box = [[x, y] for x in region.x for y in region.y]
        assert inside_polygon(np.array(box), corners).all(), region
    assert layout.spawn_evaders.y[1] > 5.0  # up in the roof, as high as a 1 m band fits


def test_separated_spawn_draws_retry_until_one_fits():
    from pursuit_mj.layout_check import sample_separated

    # five points 0.25 m apart on a line, three wanted 0.5 m apart: only {0, 0.5, 1.0} fits, and
    # a random greedy pass often takes 0.25 or 0.75 first, so a draw must retry until it fits
    line = np.array([[0.25 * i, 0.0] for i in range(5)])
    rng = np.random.default_rng(0)
    for _ in range(20):
        drawn = sample_separated(line, 3, rng, 0.5, tries=200)
        assert drawn is not None and sorted(drawn[:, 0].tolist()) == [0.0, 0.5, 1.0]
    assert sample_separated(line, 4, rng, 0.5, tries=5) is None


def test_a_task_whose_capture_radius_spans_the_spawn_gap_is_refused(tmp_path):
    path = tmp_path / "close.yaml"
    path.write_text(yaml.safe_dump(base_dict(spawn={"pursuers": SPAWN["pursuers"], "evaders": {"x": [0.2, 3.4], "y": [1.2, 1.8]}})))
    PursuitEnv(default_config(layout=str(path), fidelity="point"), seed=0)  # 0.4 m apart: fine with 0.3
    with pytest.raises(LayoutError, match="spawn regions are 0.4 m apart, within the capture_radius of 0.5 m"):
        PursuitEnv(default_config(layout=str(path), fidelity="point", capture_radius=0.5), seed=0)


def test_numbers_in_exponent_form_are_numbers_as_in_yaml_1_2(tmp_path):
    """PyYAML follows YAML 1.1, where 36e-1 without a dot is text; a layout author means 3.6."""
    path = tmp_path / "exp.yaml"
    path.write_text("name: exp\narena: {width: 36e-1, height: 5e0}\nboundary: rectangle\n"
                    "obstacles: [{cylinder: {center: [18e-1, 2.5], radius: 2E-1}}]\n"
                    "spawn:\n  pursuers: {x: [0.2, 3.4], y: [0.2, 0.8]}\n  evaders: {x: [0.2, 3.4], y: [4.2, 4.8]}\n")
    layout = load_layout(path)
    assert (layout.width, layout.height) == (3.6, 5.0)
    assert layout.obstacles[0].center == (1.8, 2.5) and layout.obstacles[0].radius == 0.2


def test_an_integer_too_long_for_a_float_is_refused_naming_the_entry(tmp_path):
    """A 400-digit integer literal is refused like any other non-number (it raised OverflowError)."""
    huge = "1" + "0" * 400
    path = tmp_path / "huge.yaml"
    path.write_text(f"arena: {{width: {huge}, height: 5.0}}\nobstacles: [{{cylinder: {{center: [1.8, {huge}], radius: 0.2}}}}]\n"
                    "spawn:\n  pursuers: {x: [0.2, 3.4], y: [0.2, 0.8]}\n  evaders: {x: [0.2, 3.4], y: [4.2, 4.8]}\n")
    with pytest.raises(LayoutError, match=r"huge.yaml: arena.width: expected a number"):
        load_layout(path)
    path.write_text(path.read_text().replace(f"width: {huge}", "width: 3.6"))
    with pytest.raises(LayoutError, match=r"huge.yaml: obstacles\[0\] \(cylinder\).center: expected two finite numbers"):
        load_layout(path)


def test_a_missing_random_obstacles_section_means_none_and_an_empty_one_the_documented_defaults():
    """DESIGN.md section 2: no section, no random obstacles; `{}` takes count 5, both kinds, 0.15-0.4 m."""
    without = base_dict()
    del without["random_obstacles"]
    assert layout_from_dict(without, "<t>").random_obstacles.count == 0
    empty = layout_from_dict(base_dict(random_obstacles={}), "<t>").random_obstacles
    assert (empty.count, tuple(empty.kinds), tuple(empty.size)) == (5, ("box", "cylinder"), (0.15, 0.4))


def _crossing_pairs_one_at_a_time(points) -> list[tuple[int, int]]:
    """Every pair of non-adjacent edges that properly cross, found pair by pair (the reference)."""
    p = np.asarray(points, float)
    n = len(p)

    def side(o, q, r):
        return np.sign((q[0] - o[0]) * (r[1] - o[1]) - (q[1] - o[1]) * (r[0] - o[0]))

    pairs = []
    for i in range(n):
        for j in range(i + 2, n):
            if i == 0 and j == n - 1:
                continue
            a, b, c, d = p[i], p[(i + 1) % n], p[j], p[(j + 1) % n]
            if side(a, b, c) * side(a, b, d) < 0 and side(c, d, a) * side(c, d, b) < 0:
                pairs.append((i, j))
    return pairs


@pytest.mark.parametrize("seed", range(40))
def test_the_border_crossing_check_finds_the_first_crossing_the_pair_by_pair_check_finds(seed):
    from pursuit_mj.layout_check import polygon_crossing

    rng = np.random.default_rng(seed)
    n = int(rng.integers(3, 12))
    if seed % 2:  # a star-shaped border: no crossing
        angles = np.sort(rng.uniform(0, 2 * np.pi, n))
        points = np.stack([np.cos(angles), np.sin(angles)], -1) * rng.uniform(0.5, 1.0, (n, 1))
    else:  # points anywhere: mostly crossing
        points = rng.uniform(0, 1, (n, 2))
    pairs = _crossing_pairs_one_at_a_time(points)
    assert polygon_crossing(points) == (pairs[0] if pairs else None)


def test_an_episode_tries_many_placements_before_a_crowded_setting_stops_the_run():
    """13 random obstacles on layout 3 found no room in 10 placements for 5 of 30 episode seeds:
    a run stopped after some hundreds of episodes. An episode now tries 200; a seed that found
    room within 10 draws exactly what it drew."""
    layout = load_layout(3)
    for seed in range(12):
        placed = layout.with_random_obstacles(np.random.default_rng(seed), 13, restarts=EPISODE_RESTARTS)
        assert placed.n_random == 13
        try:
            strict = layout.with_random_obstacles(np.random.default_rng(seed), 13)
        except LayoutError:
            continue
        assert strict == placed
    env = PursuitEnv(default_config(layout=3, random_obstacles=13, fidelity="point", max_steps=2), n_worlds=4, seed=0)
    env.reset()
    for _ in range(16):  # 8 episodes in each world, as in the run that stopped
        env.step(np.zeros((4, 3, 2)))


def test_a_door_the_coarse_grid_of_a_big_arena_misses_is_refused_saying_how_wide_a_gap_it_sees():
    """A 0.3 m door was refused in a 35 m arena, whose grid of 11.7 cm held no cell in its 0.1 m free
    band, as if walls cut the arena in two; the message now says what the grid can see."""
    side, half = 35.0, 17.5

    def doored(gap):
        return base_dict(arena={"width": side, "height": side}, random_obstacles={"count": 0},
                         obstacles=[{"wall": {"from": [0.0, half], "to": [half - gap / 2, half]}},
                                    {"wall": {"from": [half + gap / 2, half], "to": [side, half]}}],
                         spawn={"pursuers": {"x": [0.2, 3.4], "y": [0.2, 0.8]},
                                "evaders": {"x": [0.2, 3.4], "y": [side - 0.8, side - 0.2]}})

    with pytest.raises(LayoutError, match=r"cut the arena in two \(a passage needs 0.2 m, found on a grid of 11.7 cm; in an "
                                          r"arena this big the grid surely sees a gap of 0.36 m or wider, so widen a narrower one\)"):
        layout_from_dict(doored(0.3), "door.yaml")
    layout_from_dict(doored(0.36 + 0.05), "door.yaml")  # as wide as it says (plus the walls' thickness): passable


def test_a_layout_file_that_cannot_be_read_or_named_is_refused_in_one_line(tmp_path, capsys, monkeypatch):
    """An unreadable file, a path too long for the file system and a name too long to name files
    after gave OSError tracebacks (from read_text, is_dir, and `layout show` writing its picture)."""
    assert main(["layout", "check", "/proc/self/mem"]) == 2
    assert "/proc/self/mem: cannot read it (Input/output error)" in capsys.readouterr().err
    long_path = str(tmp_path / ("b" * 300 + ".yaml"))
    assert main(["layout", "check", long_path]) == 2
    assert "cannot use this path (File name too long)" in capsys.readouterr().err
    assert main(["eval", "--layouts", long_path, "--episodes", "1"]) == 2
    assert "cannot use this path (File name too long)" in capsys.readouterr().err
    named = tmp_path / "named.yaml"
    named.write_text(yaml.safe_dump(base_dict(name="a" * 300)))
    assert main(["layout", "show", str(named), "--out", str(tmp_path / "x.png")]) == 2
    assert "name 'aaaa" in (err := capsys.readouterr().err) and "300 bytes long; at most 100" in err and "Traceback" not in err
    stem = tmp_path / ("s" * 200 + ".yaml")  # no name of its own: named after the file, as long as the file system allows
    stem.write_text(yaml.safe_dump({k: v for k, v in base_dict().items() if k != "name"}))
    monkeypatch.chdir(tmp_path)
    assert main(["layout", "show", str(stem)]) == 0
    assert (tmp_path / f"layout_{'s' * 100}.png").is_file()


def test_a_slanted_wall_whose_corner_pokes_out_says_where():
    """Both its ends lie inside: "lies (partly) outside" left the user looking for what did not."""
    data = base_dict(obstacles=[{"wall": {"from": [0.0, 2.0], "to": [2.0, 3.0]}}])
    with pytest.raises(LayoutError, match=r"outside the 3.6 x 5.0 m arena: its edge reaches \(-0.011, 2.022\) m, its thickness"):
        layout_from_dict(data, "slant.yaml")


def test_layout_keys_misspelled_get_a_did_you_mean(tmp_path):
    for data, message in ((base_dict(arena={"width": 3.6, "heigth": 5.0}), r"arena: unknown key 'heigth' \(did you mean 'height'\?\)"),
                          (base_dict(obstacles=[{"cylindre": {"center": [1, 1], "radius": 0.2}}]), r"unknown obstacle kind 'cylindre' \(did you mean 'cylinder'\?\)"),
                          (base_dict(color="red"), r"unknown key 'color' \(valid: ")):
        with pytest.raises(LayoutError, match=message):
            layout_from_dict(data, "typo.yaml")


def test_a_yaml_error_without_a_line_says_where_and_a_non_utf8_byte_is_named(tmp_path):
    ctrl, latin = tmp_path / "ctrl.yaml", tmp_path / "latin.yaml"
    ctrl.write_text("name: a\x07b\n")
    latin.write_bytes(b"name: caf\xe9\n")
    with pytest.raises(LayoutError, match=r"ctrl.yaml: not valid YAML, character 8: unacceptable character #x0007"):
        load_layout(ctrl)
    with pytest.raises(ValueError, match=r"latin.yaml: not a text \(YAML\) file \(byte 10 is not UTF-8\)"):
        load_layout(latin)


def test_layout_check_names_overlapping_spawn_regions_before_the_random_obstacles_room(tmp_path, capsys):
    """It said "no room for random obstacle 1 of 5" where the spawn regions overlapped, which eval named."""
    path = tmp_path / "overlap.yaml"
    path.write_text("arena: {width: 3.6, height: 5.0}\nrandom_obstacles: {count: 5}\nspawn:\n"
                    "  pursuers: {x: [0.2, 3.4], y: [0.2, 2.8]}\n  evaders: {x: [0.2, 3.4], y: [2.5, 4.8]}\n")
    assert main(["layout", "check", str(path)]) == 2
    err = capsys.readouterr().err
    assert "spawn regions overlap" in err and "no room for random obstacle" not in err, err


def test_the_episode_seed_in_layout_show_help_is_the_one_render_reports(capsys):
    """The help quoted a seed (2968811710) that render no longer prints for its first episode."""
    from pursuit_cli.render_cmd import table_episode_seeds
    from pursuit_mj.config import default_config

    with pytest.raises(SystemExit):
        main(["layout", "show", "--help"])
    help_text = " ".join(capsys.readouterr().out.split())
    assert f"(seed {table_episode_seeds(default_config(), 0, 1)[0]})" in help_text, help_text


def test_layout_show_draws_an_episode_whose_placement_needed_more_than_the_checks_restarts(tmp_path, capsys):
    """An episode tries EPISODE_RESTARTS placements (layout 3 with 13 random obstacles: seed 1
    finds room only after the 10 the layout check tries); `layout show --seed 1 --count 13`
    said 'no room' for the episode the env plays with those obstacles."""
    from pursuit_mj.layout_preview import preview_layout

    env = PursuitEnv(default_config(layout=3, random_obstacles=13, fidelity="point"), n_worlds=1, seed=0)
    env.reset(seeds=[1])
    assert preview_layout(load_layout(3), 1, 13) == env.world_layouts[0]
    assert main(["layout", "show", "3", "--seed", "1", "--count", "13", "-o", str(tmp_path / "crowded.png")]) == 0, capsys.readouterr().err


def test_a_border_polygon_far_outside_the_arena_is_refused_without_numpy_overflow_warnings(tmp_path, capsys):
    """A point at 1e300 m overflowed the self-crossing checks: a page of numpy RuntimeWarnings
    came before the one-line error naming the point outside the arena."""
    import warnings

    data = base_dict(boundary={"polygon": [[0.0, 0.0], [1e300, 0.0], [0.0, 1e300]]})
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(LayoutError, match=r"far.yaml: boundary polygon point \[1e\+300, 0.0\] lies outside the 3.6 x 5.0 m arena"):
            layout_from_dict(data, "far.yaml")
    path = tmp_path / "far.yaml"
    path.write_text(yaml.safe_dump(data))
    assert main(["layout", "check", str(path)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "lies outside the 3.6 x 5.0 m arena" in err, err


@pytest.mark.parametrize("obstacle", [{"wall": {"from": [1.0, 2.5], "to": [2.0, 2.5], "thickness": 1e300}},
                                      {"cylinder": {"center": [1.0, 2.5], "radius": 1e300}},
                                      {"box": {"center": [1e308, 2.5], "size": [1.7e308, 0.2]}}])
def test_an_obstacle_of_absurd_size_is_refused_in_a_short_line_without_overflow_warnings(obstacle):
    """Its edge was printed with {:.3f}: 'its edge reaches (2.000, 500000000000000026...' ran to 300 digits."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(LayoutError, match=r"huge.yaml: obstacles\[0\] .* lies \(partly\) outside the 3.6 x 5.0 m arena: "
                                              r"its edge reaches \(\S+, \S+\) m") as info:
            layout_from_dict(base_dict(obstacles=[obstacle]), "huge.yaml")
    assert len(str(info.value)) < 250, str(info.value)


def test_a_border_polygon_closed_by_repeating_its_first_point_is_told_to_leave_it_out():
    """A ring closed as GeoJSON closes it was refused as 'point 4 repeats point 0: the border must
    not touch itself', which sent the user looking for a place where the border touches itself."""
    ring = [[0.0, 0.0], [3.6, 0.0], [3.6, 5.0], [0.0, 5.0], [0.0, 0.0]]
    with pytest.raises(LayoutError, match=r"ring.yaml: boundary.polygon: the last point \[0.0, 0.0\] repeats the first: "
                                          r"the border closes by itself; leave the last point out"):
        layout_from_dict(base_dict(boundary={"polygon": ring}), "ring.yaml")
    layout_from_dict(base_dict(boundary={"polygon": ring[:-1]}), "ring.yaml")


def test_a_huge_random_obstacle_count_is_shown_short(tmp_path, capsys):
    """random_obstacles.count: 1e300 is a whole number; the refusal printed all its 301 digits."""
    from pursuit_cli import main
    from pursuit_mj.layout import builtin_layout_path

    path = tmp_path / "a.yaml"
    path.write_text(builtin_layout_path(0).read_text().replace("count: 5,", "count: 1e300,"))
    assert main(["layout", "check", str(path)]) == 2
    err = capsys.readouterr().err
    assert "random_obstacles.count: 1e+300 is more than" in err and len(err) < 300, err


@pytest.mark.parametrize("argv, said", [
    (["layout", "new", "n1/x/l.yaml", "--width", "-3"], "--width: must be a number > 0"),
    (["layout", "new", "n1/x/l.txt"], "expected a .yaml file name"),
    (["layout", "show", "0", "--out", "n1/x/l.png", "--count", "60"], "--count 60: "),
])
def test_a_layout_file_refused_leaves_no_folder_it_made(tmp_path, capsys, monkeypatch, argv, said):
    """layout new and layout show check that the file can be written (which makes its folder) before
    they build or draw the layout: a bad --width, a name that is not .yaml, a --count with no room
    left the empty n1/x/ behind."""
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    assert said in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


# ----------------------------------------------------------------------------- mutation audit


@pytest.mark.parametrize(
    "data, message",
    [  # each just past its limit (the limits themselves are accepted: see the test below)
        (base_dict(obstacles=[{"box": {"center": [1.8, 2.5], "size": [0.0, 0.5]}}]), r"obstacles\[0\] \(box\).size: extents must be > 0, got \[0.0, 0.5\]"),
        (base_dict(obstacles=[{"box": {"center": [1.8, 2.5], "size": [0.6, 0.2], "yaw": 6.3}}]), r"\(box\).yaw: 6.3 is beyond \+-2 pi"),
        (base_dict(spawn={"pursuers": {"x": [0.2, 3.4], "y": [0.8, 0.2]}, "evaders": SPAWN["evaders"]}), r"spawn.pursuers: ranges must be \[low, high\]"),
        (base_dict(random_obstacles={"count": 65}), r"random_obstacles.count: 65 is more than 64"),
        (base_dict(random_obstacles={"count": 2, "size": [0.0, 0.3]}), r"random_obstacles.size: expected \[min, max\] with 0 < min <= max"),
        (base_dict(arena={"width": 50.01, "height": 5.0}), r"arena.width: 50.01 m is beyond the 50 m"),
        (base_dict(name="n" * 101), r"name 'n{40}\.\.\.': 101 bytes long; at most 100"),
    ],
)
def test_a_layout_value_just_past_its_limit_is_refused(data, message):
    with pytest.raises(LayoutError, match=message):
        layout_from_dict(data, "bad.yaml")


def test_layout_values_at_their_limits_are_accepted_and_a_spawn_line_is_no_point():
    at = base_dict(name="n" * 100, obstacles=[{"box": {"center": [1.8, 2.5], "size": [0.6, 0.2], "yaw": 6.28}}],
                   spawn={"pursuers": {"x": [0.6, 0.6], "y": [0.2, 1.4]}, "evaders": SPAWN["evaders"]})
    layout = layout_from_dict(at, "at.yaml")
    assert not layout.spawn_pursuers.is_point  # a line x = 0.6 holds a team along it
    from pursuit_mj.layout_check import check_spawn_capacity

    check_spawn_capacity(layout, 3, 1, 0.4)


def test_obstacles_placed_at_random_twice_are_all_counted_as_random():
    rng = np.random.default_rng(0)
    layout = load_layout(0).with_random_obstacles(rng, 2).with_random_obstacles(rng, 1)
    assert layout.n_random == 3 and len(layout.obstacles) == 3


@pytest.mark.parametrize("ref", [True, np.bool_(False)])
def test_a_boolean_is_no_built_in_layout_index(ref):
    from pursuit_mj.layout import resolve_layout_ref

    with pytest.raises(LayoutError, match=r"expected a built-in index 0-3 or a file path"):
        resolve_layout_ref(ref)


@pytest.mark.parametrize("points, said", [(["0,0", "3,0"], "largest y is 0"), (["0,0"], "largest x is 0")])
def test_layout_new_with_points_that_span_no_area_names_points_not_a_flag_left_out(points, said, tmp_path, capsys):
    """--points 0,0 3,0 (two corners on a line) was refused as '--height: must be a number > 0, got
    0.0', about a flag the user never gave (the arena is sized to the points without it)."""
    assert main(["layout", "new", str(tmp_path / "p.yaml"), "--border", "polygon", "--points", *points]) == 2
    err = capsys.readouterr().err
    assert f"--points {' '.join(points)}: " in err and said in err and "--height: must" not in err, err
    assert "--width: must" not in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "p.yaml").exists()


@pytest.mark.parametrize("argv, said", [
    (["new", "{tmp}/s.yaml", "--seed", "5"], "--seed 5: seeds the obstacles that --random places, and none is asked for"),
    (["show", "3", "-o", "{tmp}/s.png", "--no-random", "--seed", "5"], "--seed 5: draws random obstacles, which --no-random leaves out"),
    (["show", "3", "-o", "{tmp}/s.png", "--no-random", "--obstacle-clearance", "0.12"],
     "--obstacle-clearance 0.12: draws random obstacles, which --no-random leaves out"),
])
def test_a_layout_flag_that_would_do_nothing_is_refused_not_ignored(argv, said, tmp_path, capsys):
    """layout new --seed 5 without --random, and layout show --no-random --seed 5, wrote the same
    file as without the flag, without a word (show refused --count with --no-random already)."""
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    assert main(["layout", *argv]) == 2
    err = capsys.readouterr().err
    assert said in err and len(err.strip().splitlines()) == 1, err
    assert list(tmp_path.iterdir()) == []
    # the seeds the flags default to still give the same files as before
    assert main(["layout", "new", str(tmp_path / "a.yaml"), "--random", "2"]) == 0
    assert main(["layout", "new", str(tmp_path / "b.yaml"), "--random", "2", "--seed", "0", "--name", "a"]) == 0
    assert (tmp_path / "a.yaml").read_text() == (tmp_path / "b.yaml").read_text()



def test_a_refused_layout_file_named_through_dot_dot_keeps_the_folder_it_names(tmp_path, capsys, monkeypatch):
    """'layout new new/../keep/l.yaml' makes new/ (to reach keep/, which was there, empty): refused, it
    removed keep/ as well as new/, since new/../keep could not be found when it started."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "keep").mkdir()
    assert main(["layout", "new", "new/../keep/l.yaml", "--width", "-3"]) == 2
    assert "--width: must be a number > 0" in capsys.readouterr().err
    assert [p.name for p in tmp_path.iterdir()] == ["keep"]


def _design_layout_section() -> str:
    text = (Path(__file__).resolve().parents[1] / "docs" / "DESIGN.md").read_text()
    return text.split("\n## 2. ", 1)[1].split("\n## ", 1)[0]


def test_the_loader_takes_exactly_the_keys_of_the_documented_layout_format(monkeypatch):
    """Every key of DESIGN.md section 2's example is accepted and read, and every key the loader
    accepts (each mapping it reads, the circle border's too) is one the example names."""
    import pursuit_mj.layout as layout_module

    block = re.search(r"```yaml\n(.*?)```", _design_layout_section(), re.S)[1]
    documented = set(re.findall(r"(\w+):", block))
    accepted = set()
    read = layout_module._mapping

    def recording(value, where, keys, required):
        accepted.update(keys)
        return read(value, where, keys, required)

    monkeypatch.setattr(layout_module, "_mapping", recording)
    data = yaml.safe_load(block)
    layout = layout_from_dict(data, "corridor.yaml")
    assert [type(o).__name__ for o in layout.obstacles] == ["Box", "Cylinder", "Wall"]
    assert (layout.width, layout.height, layout.random_obstacles.count) == (3.6, 5.0, 5)
    circle = re.search(r"\{circle: \{center: \[x, y\], radius: r\}\}", block)
    assert circle, "the example's comment lost the circle border's form"
    with pytest.raises(LayoutError):  # read (its keys recorded), then refused: the example's spawn lies outside it
        layout_from_dict({**data, "boundary": {"circle": {"center": [1.8, 2.5], "radius": 1.0}}}, "corridor.yaml")
    assert accepted <= documented, f"the loader accepts {sorted(accepted - documented)}, which DESIGN.md section 2 never names"
    assert documented - accepted <= {"polygon", "circle", "box", "cylinder", "wall"}  # kinds, not mapping keys


def test_the_optional_layout_keys_take_the_defaults_the_docs_give(tmp_path):
    """The loader fills in name, boundary, obstacles, random_obstacles, a box's yaw and a wall's
    thickness when a file leaves them out; DESIGN.md section 2 said so for random_obstacles alone
    (in a comment), so a reader could not tell which keys a file may leave out."""
    prose = " ".join(_design_layout_section().split())
    said = re.search(r"Only `arena` and `spawn` are required\. Left out, `name` is the file's name without "
                     r"`\.yaml`, `boundary` is `rectangle`, `obstacles` and `random_obstacles` are none, a box's `yaw` is "
                     r"(\S+) and a wall's `thickness` (\S+) m\.", prose)
    assert said, "DESIGN.md section 2 does not say which layout keys are optional and what they default to"
    path = tmp_path / "bare.yaml"
    path.write_text("arena: {width: 3.6, height: 5.0}\n"
                    "obstacles:\n  - box: {center: [1.2, 2.5], size: [0.2, 1.0]}\n"
                    "  - wall: {from: [2.0, 2.0], to: [3.0, 2.0]}\n"
                    "spawn:\n  pursuers: {x: [0.2, 3.4], y: [0.2, 0.8]}\n  evaders: {x: [0.2, 3.4], y: [4.2, 4.8]}\n")
    layout = load_layout(path)
    box, wall = layout.obstacles
    assert (layout.name, layout.boundary.kind, layout.random_obstacles.count) == ("bare", "rectangle", 0)
    assert (box.yaw, wall.thickness) == (float(said[1]), float(said[2]))
    for required in ("arena", "spawn"):
        with pytest.raises(LayoutError, match=f"missing key '{required}'"):
            layout_from_dict({k: v for k, v in yaml.safe_load(path.read_text()).items() if k != required}, "x.yaml")
    minimal = tmp_path / "minimal.yaml"
    minimal.write_text("arena: {width: 3.6, height: 5.0}\n"
                       "spawn:\n  pursuers: {x: [0.2, 3.4], y: [0.2, 0.8]}\n  evaders: {x: [0.2, 3.4], y: [4.2, 4.8]}\n")
    assert load_layout(minimal).obstacles == ()


@pytest.mark.parametrize("kinds", [["box", "cylinder"], ["cylinder", "box"], ["box"], ["cylinder"]])
def test_candidates_computed_from_raw_outputs_are_those_drawn_one_at_a_time(kinds):
    """Candidates are computed in a batch from the generator's raw 64-bit outputs (a PCG64's; numpy's
    own draws from them cost microseconds each): each the same to the bit as `_draw` gives, and the
    generator left where drawing the first j + 1 one at a time leaves it, also with half of a 32-bit
    draw pending; another bit generator is drawn from one at a time."""
    from pursuit_mj.layout_random import candidate_batch, draw_region, _draw

    layout = layout_from_dict(base_dict(random_obstacles={"count": 3, "kinds": kinds, "size": [0.15, 0.4]}), "t.yaml")
    region = draw_region(layout)
    for seed in range(40):
        for pending, k in ((False, 1), (False, 64), (True, 7), (True, 64)):
            def fresh():
                rng = np.random.default_rng(seed) if seed % 5 else np.random.Generator(np.random.MT19937(seed))
                if pending:
                    rng.integers(2)  # takes half of a 64-bit output, keeps the other half for the next 32-bit draw
                return rng

            one_at_a_time, batched = fresh(), fresh()
            want = np.array([_draw(layout, region, one_at_a_time) for _ in range(k)])
            batch = candidate_batch(layout, region, batched, k)
            assert batch.rows.tobytes() == want.tobytes(), (seed, k)
            j = seed % k
            again = fresh()
            for _ in range(j + 1):
                _draw(layout, region, again)
            batch.take(j)
            assert repr(batched.bit_generator.state) == repr(again.bit_generator.state), (seed, k, j)  # repr: MT19937's key array
            assert batched.random() == again.random() and batched.integers(2) == again.integers(2)


def _greedy_spawn_reference(points, n, rng, separation, tries):
    """sample_separated as first written: walk each permutation point by point, taking those far enough from all taken."""
    for _ in range(tries):
        chosen = []
        for idx in rng.permutation(len(points)):
            q = points[idx]
            if all(np.hypot(*(q - c)) >= separation for c in chosen):
                chosen.append(q)
                if len(chosen) == n:
                    return np.array(chosen)
    return None


@pytest.mark.parametrize("index", [0, 1, 2, 3])
def test_spawn_draws_are_the_plain_greedy_walks_draws(index):
    """sample_separated jumps between still-allowed points instead of testing each point against
    every one taken (a team that does not fit was refused after 3 s); every episode's spawn must
    stay the draw the plain walk makes: the same points, the same random numbers used."""
    from pursuit_mj.layout_check import SPAWN_SEPARATION, check_spawn_capacity, free_spawn_points, sample_separated

    layout = load_layout(index)
    for region in (layout.spawn_pursuers, layout.spawn_evaders):
        points = free_spawn_points(layout, region)
        for n, separation, seed in [(1, 0.4, 0), (3, 0.4, 1), (6, 0.3, 2), (12, 0.4, 3), (40, 0.4, 4), (5, 0.137, 5)]:
            rng, ref_rng = np.random.default_rng(seed), np.random.default_rng(seed)
            got, want = sample_separated(points, n, rng, separation, tries=3), _greedy_spawn_reference(points, n, ref_rng, separation, 3)
            assert (got is None) == (want is None) and (want is None or got.tobytes() == want.tobytes())
            assert rng.integers(1 << 62) == ref_rng.integers(1 << 62)  # the same random numbers used
    with pytest.raises(ValueError, match="cannot reliably hold 16 pursuers"):
        check_spawn_capacity(layout, 16, 1, SPAWN_SEPARATION)


def test_a_spawn_point_exactly_the_clearance_from_the_border_is_accepted():
    """A fixed start 0.2 m from the border is 'clear of the border' as docs/DESIGN.md has it; in a
    1 m arena y = 0.8 lies 0.19999999999999996 m from the top in floats, and was refused as
    'has no free point 0.2 m away ... (spawn region inside an obstacle?)'."""
    from pursuit_mj.layout_check import check_layout, free_spawn_points

    layout = layout_from_dict({"arena": {"width": 1.0, "height": 1.0},
                               "spawn": {"pursuers": {"x": [0.2, 0.2], "y": [0.2, 0.2]},
                                         "evaders": {"x": [0.8, 0.8], "y": [0.8, 0.8]}}}, source="tiny.yaml")
    check_layout(layout)
    assert free_spawn_points(layout, layout.spawn_evaders).tolist() == [[0.8, 0.8]]


def test_a_spawn_region_with_no_free_point_names_the_obstacles_that_cover_it():
    """'spawn.pursuers ... has no free point 0.2 m away from obstacles and the border (spawn region
    inside an obstacle?)' left the user to find which of the file's obstacles it meant; the refusal
    names them (or says that the border alone leaves no room), as DESIGN.md promises an error
    naming the offending entry."""
    covering = [{"cylinder": {"center": [3.0, 4.0], "radius": 0.2}},
                {"box": {"center": [1.0, 0.5], "size": [2.0, 1.0]}}, {"box": {"center": [2.8, 0.5], "size": [1.6, 1.0]}}]
    with pytest.raises(LayoutError, match=r"spawn.pursuers x=\[0.2, 3.4\] y=\[0.2, 0.8\] has no free point 0.2 m away from "
                                          r"obstacles and the border: obstacles\[1\] \(box centre \[1.0, 0.5\] size \[2.0, 1.0\]\) "
                                          r"and obstacles\[2\] \(box centre \[2.8, 0.5\] size \[1.6, 1.0\]\) cover it$"):
        layout_from_dict(base_dict(obstacles=covering), "covered.yaml")
    edge = base_dict(spawn={"pursuers": {"x": [0.1, 3.5], "y": [0.1, 0.15]}, "evaders": SPAWN["evaders"]})
    with pytest.raises(LayoutError, match=r"spawn.pursuers x=\[0.1, 3.5\] y=\[0.1, 0.15\] has no free point 0.2 m away from "
                                          r"obstacles and the border: all of it lies within 0.2 m of the border$"):
        layout_from_dict(edge, "edge.yaml")


def test_layout_new_names_every_covering_obstacle_by_its_flag(tmp_path, capsys):
    """Two --box flags covering the pursuers' band: the refusal named the first by its flag and the
    second as obstacles[1], an index the user never wrote."""
    out = tmp_path / "y.yaml"
    assert main(["layout", "new", str(out), "--box", "1", "0.5", "2", "1", "--box", "2.8", "0.5", "1.6", "1"]) == 2
    err = capsys.readouterr().err
    assert ("the 1st --box 1 0.5 2 1 (box centre [1.0, 0.5] size [2.0, 1.0]) and the 2nd --box 2.8 0.5 1.6 1 "
            "(box centre [2.8, 0.5] size [1.6, 1.0]) cover it") in err, err
    assert "obstacles[" not in err and not out.exists()
