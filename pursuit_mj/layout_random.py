"""Seeded placement of random obstacles that avoid spawn regions, the border and each other,
and leave the passages between the spawn regions open."""

from __future__ import annotations

import numpy as np

from .geometry import ObstacleSet, border_distance, inside_boundary, obstacle_distance
from .layout_check import check_passages, passage_fault

MAX_TRIES = 1000  # draws for one obstacle
RESTARTS = 10  # placements of all obstacles, before no room is reported (layout check: stricter than an episode)
EPISODE_RESTARTS = 200  # the same in an episode's reset: a crowded setting that finds room in 1 of 20
# placements must not stop a run after hours (a seed that finds room within RESTARTS draws what it drew)
PASSAGE_DRAWS = 50  # placements that may close a passage, before the setting is reported impossible


def _spawn_distance(layout, pts: np.ndarray) -> np.ndarray:
    """Distance (P,) from points to the nearest spawn rectangle (0 inside)."""
    out = np.full(len(pts), np.inf)
    for r in (layout.spawn_pursuers, layout.spawn_evaders):
        dx = np.maximum(np.maximum(r.x[0] - pts[:, 0], pts[:, 0] - r.x[1]), 0)
        dy = np.maximum(np.maximum(r.y[0] - pts[:, 1], pts[:, 1] - r.y[1]), 0)
        out = np.minimum(out, np.hypot(dx, dy))
    return out


def place_random_obstacles(layout, rng: np.random.Generator, count: int, clearance: float, count_source: str | None = None,
                           passage_clearance: float = 0.0, passage_source: str = "passage_clearance",
                           restarts: int = RESTARTS) -> list:
    """Draw `count` obstacles of the layout's kinds and size range; LayoutError if no room, naming
    `count_source` (where the count came from; default: the file's random_obstacles.count).

    Obstacles keep `clearance` (m) from each other, the fixed obstacles, the border and the
    spawn regions. That leaves every passage of the layout open for a drone centre keeping
    `passage_clearance` (m) from obstacles as long as 2 x passage_clearance <= clearance; above
    that, a placement that cuts a spawn point off from the other team is drawn again from the
    same rng (up to PASSAGE_DRAWS placements, then LayoutError naming `passage_source`).
    """
    for _ in range(PASSAGE_DRAWS):
        placed = _place(layout, rng, count, clearance, count_source, restarts)
        if 2 * passage_clearance <= clearance or passage_fault(_with(layout, placed), passage_clearance) is None:
            return placed
    check_passages(layout, passage_clearance, passage_source)  # the fixed obstacles alone close a passage
    from .layout import LayoutError

    spec, counts = layout.random_obstacles, count_source or "random_obstacles.count"
    raise LayoutError(
        f"{layout.source}: none of {PASSAGE_DRAWS} placements of {count} random obstacles (sizes {list(spec.size)} m, "
        f"{clearance:g} m apart) left every spawn point reachable from the other team for a drone keeping "
        f"{passage_source} {passage_clearance:g} m from obstacles (a passage needs {2 * passage_clearance:g} m); "
        f"lower {passage_source}, {counts} or random_obstacles.size in {layout.source}"
    )


def _place(layout, rng: np.random.Generator, count: int, clearance: float, count_source: str | None,
           restarts: int = RESTARTS) -> list:
    """One placement of `count` obstacles `clearance` (m) apart; LayoutError if no room.

    Obstacles are placed one by one; when one finds no room, the placement starts over (up to
    `restarts` times, drawing on from the same rng): early obstacles can block the rest in one
    draw and leave room in another, and one episode's unlucky draw must not stop a run.
    """
    from .layout import LayoutError

    spec = layout.random_obstacles
    border = layout.border()
    for _ in range(restarts):
        placed = _place_once(layout, rng, count, clearance, border)
        if len(placed) == count:
            return placed
    raise LayoutError(
        f"{layout.source}: no room for random obstacle {len(placed) + 1} of {count} in {restarts} tries at placing all {count} "
        f"(sizes {list(spec.size)} m, clearance {clearance} m); "
        + (f"lower {count_source}" if count_source else "lower random_obstacles.count or .size")
    )


def _place_once(layout, rng: np.random.Generator, count: int, clearance: float, border: np.ndarray) -> list:
    """Up to `count` obstacles placed one by one; fewer if one finds no room in MAX_TRIES draws.

    Each obstacle takes the first of its draws that fits. The draws are judged in batches (the
    geometry is vectorised over points); the generator is then wound back to the batch's start
    and redrawn up to the one taken, so it is left exactly where drawing them one at a time
    would leave it, and a seed places the same obstacles either way.
    """
    placed: list = []
    others = ObstacleSet.from_layout(layout, include_border=False)
    region = draw_region(layout)
    for _ in range(count):
        tries, batch = 0, FIRST_BATCH
        while tries < MAX_TRIES:
            k = min(batch, MAX_TRIES - tries)
            candidates = candidate_batch(layout, region, rng, k)
            draws = candidates.rows  # (k, 6)
            fits = _fits(layout, border, others, draws[:, 2:4], _reach(draws), clearance)
            if fits.any():
                j = int(np.argmax(fits))
                placed.append(_obstacle(layout, candidates.take(j)))
                others = ObstacleSet.from_layout(_with(layout, placed), include_border=False)
                break
            candidates.take(k - 1)
            tries += k
            batch = min(2 * batch, MAX_BATCH)
        else:
            return placed
    return placed


FIRST_BATCH, MAX_BATCH = 32, 256  # draws judged at once: few while most fit, more where room is scarce


def draw_region(layout) -> tuple[float, float, float, float]:
    """(x0, x1, y0, y1) m: the box random obstacle centres are drawn in, the border's bounding box
    within the arena. For the built-in layouts it is the arena itself; a small round border in a
    big arena would waste most draws outside it and report no room where there is."""
    b = layout.boundary
    if b.kind == "circle":
        x0, x1, y0, y1 = b.center[0] - b.radius, b.center[0] + b.radius, b.center[1] - b.radius, b.center[1] + b.radius
    elif b.kind == "polygon":
        p = np.asarray(b.points, dtype=np.float64)
        x0, x1, y0, y1 = p[:, 0].min(), p[:, 0].max(), p[:, 1].min(), p[:, 1].max()
    else:
        x0, x1, y0, y1 = 0.0, layout.width, 0.0, layout.height
    return float(max(x0, 0.0)), float(min(x1, layout.width)), float(max(y0, 0.0)), float(min(y1, layout.height))


def _draw(layout, region: tuple[float, float, float, float], rng: np.random.Generator) -> tuple[float, ...]:
    """One candidate's numbers, drawn from rng in a fixed order: (kind index into
    random_obstacles.kinds, size m, centre x m, centre y m, aspect, yaw rad); a cylinder draws
    no aspect or yaw (NaN). The centre is uniform in `region` (`draw_region`)."""
    spec = layout.random_obstacles
    kind = int(rng.integers(len(spec.kinds)))
    size = rng.uniform(spec.size[0], spec.size[1])
    x, y = rng.uniform(region[0], region[1]), rng.uniform(region[2], region[3])
    if spec.kinds[kind] == "cylinder":
        return kind, size, x, y, np.nan, np.nan
    return kind, size, x, y, rng.uniform(0.5, 1.0), rng.uniform(0, np.pi)


class _DrawnOneByOne:
    """k candidates drawn with `_draw` (rows (k, 6)); take(j) winds the generator back to where
    drawing the first j + 1 left it. For any bit generator."""

    def __init__(self, layout, region: tuple[float, float, float, float], rng: np.random.Generator, k: int):
        self.rng, self.layout, self.region = rng, layout, region
        self.start = rng.bit_generator.state
        self.rows = np.array([_draw(layout, region, rng) for _ in range(k)])

    def take(self, j: int) -> np.ndarray:
        """Row j, with the generator left as drawing rows 0..j one at a time leaves it."""
        self.rng.bit_generator.state = self.start
        for _ in range(j + 1):
            _draw(self.layout, self.region, self.rng)
        return self.rows[j]


_TO_DOUBLE = 1.0 / 9007199254740992.0  # numpy's next_double: the top 53 bits of a 64-bit output, times 2^-53


class _ComputedFromRaw:
    """The rows `_DrawnOneByOne` draws, computed at once from a PCG64's raw 64-bit outputs (numpy's
    draws from them cost a microsecond each, and a crowded layout check draws some 10^6). What
    `_draw` asks numpy for, and how numpy answers (numpy 2's Generator on PCG64):
    - integers(n) of n <= 2 kinds: none for one kind; else the top bit of a 32-bit draw (Lemire's
      method, which never rejects for n = 2). A 32-bit draw is the low half of a new 64-bit output,
      whose high half the bit generator keeps (has_uint32, uinteger) for the next 32-bit draw;
    - uniform(lo, hi): lo + (hi - lo) * (output >> 11) * 2^-53, one output each.
    tests/test_layout.py compares them to `_draw`'s to the bit, the generator's state with them."""

    def __init__(self, layout, region: tuple[float, float, float, float], rng: np.random.Generator, k: int):
        spec = layout.random_obstacles
        self.bits = rng.bit_generator
        self.start = self.bits.state
        has, half = self.start["has_uint32"], self.start["uinteger"]
        raw = self.bits.random_raw(6 * k + 1)  # enough for k boxes and their kinds
        uniform = (raw >> np.uint64(11)).astype(np.float64) * _TO_DOUBLE
        outputs = raw.tolist() if len(spec.kinds) > 1 else []
        kind, first = np.zeros(k, np.int64), np.empty(k, np.int64)
        self.after: list[tuple[int, int, int]] = []  # per candidate: (outputs used, has_uint32, uinteger)
        used = 0
        for i in range(k):
            if outputs:
                if has:
                    bits32, has = half, 0
                else:
                    bits32, half, has = outputs[used] & 0xFFFFFFFF, outputs[used] >> 32, 1
                    used += 1
                kind[i] = (bits32 * len(spec.kinds)) >> 32
            first[i] = used
            used += 3 if spec.kinds[kind[i]] == "cylinder" else 5
            self.after.append((used, has, half))
        box = np.array([spec.kinds[c] != "cylinder" for c in kind])
        lo, hi = float(spec.size[0]), float(spec.size[1])
        rows = np.full((k, 6), np.nan)
        rows[:, 0] = kind
        rows[:, 1] = lo + (hi - lo) * uniform[first]
        rows[:, 2] = region[0] + (region[1] - region[0]) * uniform[first + 1]
        rows[:, 3] = region[2] + (region[3] - region[2]) * uniform[first + 2]
        rows[box, 4] = 0.5 + (1.0 - 0.5) * uniform[first[box] + 3]
        rows[box, 5] = 0.0 + (np.pi - 0.0) * uniform[first[box] + 4]
        self.rows = rows

    def take(self, j: int) -> np.ndarray:
        """Row j, with the generator left as drawing rows 0..j one at a time leaves it."""
        used, has, half = self.after[j]
        self.bits.state = self.start
        self.bits.advance(used)  # also clears the kept half, set again below
        state = self.bits.state
        state["has_uint32"], state["uinteger"] = has, half
        self.bits.state = state
        return self.rows[j]


def candidate_batch(layout, region: tuple[float, float, float, float], rng: np.random.Generator, k: int):
    """k candidates (rows (k, 6) of `_draw`'s numbers) as drawing them one at a time from rng gives;
    take(j) returns row j and leaves rng where drawing rows 0..j would have. Computed from raw
    outputs for numpy's default bit generator with at most two obstacle kinds, else drawn."""
    if type(rng.bit_generator) is np.random.PCG64 and len(layout.random_obstacles.kinds) <= 2:
        return _ComputedFromRaw(layout, region, rng, k)
    return _DrawnOneByOne(layout, region, rng, k)


def _reach(draws: np.ndarray) -> np.ndarray:
    """(K,) m: how far each drawn obstacle (draws (K, 6) of `_draw`) extends from its centre."""
    size, aspect = draws[:, 1], draws[:, 4]
    return np.where(np.isnan(aspect), size / 2, 0.5 * np.hypot(size, size * np.nan_to_num(aspect)))


def _obstacle(layout, draw):
    """The Cylinder or Box of one candidate's numbers (a `_draw`, or a row of them)."""
    from .layout import Box, Cylinder

    kind, size, x, y, aspect, yaw = draw
    if layout.random_obstacles.kinds[int(kind)] == "cylinder":
        return Cylinder((float(x), float(y)), float(size / 2))
    return Box((float(x), float(y)), (float(size), float(size * aspect)), float(yaw))


def _fits(layout, border: np.ndarray, others: ObstacleSet, centers: np.ndarray, reach: np.ndarray, clearance: float) -> np.ndarray:
    """(K,) bool: the candidates with centres (K, 2) m and reaches (K,) m lie inside the border
    and keep `clearance` from it, from the spawn regions and from the obstacles already there."""
    need = reach + clearance
    return (inside_boundary(layout, centers)
            & ~(border_distance(centers, border) < need)
            & ~(_spawn_distance(layout, centers) < need)
            & ~(obstacle_distance(centers, others, with_border=False) < need))


def _with(layout, extra: list):
    import dataclasses

    return dataclasses.replace(layout, obstacles=layout.obstacles + tuple(extra))
