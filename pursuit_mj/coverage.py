"""A per-pursuer coverage map built from range readings: where to sweep next, and a path there.

No map is given: each pursuer builds its own grid in the layout frame (origin at the arena's
lower-left corner, `cell` m cells; the grid grows when a reading lands beyond it). From its
rays it marks cells a ray crossed as *free*, cells where a ray ended on something as
*blocked*, and cells within `see_radius` along a ray as *seen now*; cells near a visible
teammate count as seen too (the teammate looks there). The sweep goal is the free cell
unseen for longest, traded against distance; a wavefront (4-connected, a few relaxation
passes per step) spreads the path length to the goal over passable cells (cells beside
obstacles cost more, so paths keep to wide passages), and the pursuer follows it down. Arrays are (W, N, GX, GY).
"""

from __future__ import annotations

import dataclasses

import numpy as np

_OFFSETS = ((1, 0), (-1, 0), (0, 1), (0, -1))


def check_tuning(params, positive: tuple[str, ...] = (), integers: tuple[str, ...] = (), skip: tuple[str, ...] = ()) -> None:
    """ValueError naming the field of dataclass `params` that is not a finite number >= 0 (> 0
    for those in `positive`; an integer >= 0 for those in `integers`); fields in `skip` are not checked."""
    who = type(params).__name__
    for f in dataclasses.fields(params):
        if f.name in skip:
            continue
        value = getattr(params, f.name)
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
            ok = False
        elif f.name in integers:
            ok = isinstance(value, (int, np.integer)) and value >= 0
        else:
            ok = np.isfinite(value) and (value > 0 if f.name in positive else value >= 0)
        if not ok:
            kind = "an integer >= 0" if f.name in integers else f"a number {'>' if f.name in positive else '>='} 0"
            unit = " (m)" if f.name == "cell" else ""
            raise ValueError(f"{who}.{f.name}: expected {kind}{unit}, got {value!r}")


@dataclasses.dataclass(frozen=True)
class CoverageParams:
    """Grid, scoring and planning settings; distances in m, times in s."""

    cell: float = 0.2  # cell width (m)
    see_radius: float = 1.2  # along a ray, cells this close count as seen (m, capped by perception)
    mate_radius: float = 0.8  # cells this close to a visible teammate count as seen (m)
    stale_time: float = 40.0  # a cell unseen for this long is as good as never seen (s)
    distance_scale: float = 5.0  # 1 of score is worth this much extra travel (m)
    keep_bonus: float = 0.15  # score bonus of the current goal (hysteresis against dithering)
    mate_penalty: float = 0.5  # score penalty of cells near a visible teammate
    relax_passes: int = 4  # wavefront passes per step (the path front moves this many cells)
    wall_cost: float = 4.0  # extra path cost of a cell beside a blocked one (keeps paths off narrow gaps)
    patience: float = 4.0  # a goal whose path has not reached the pursuer by then is dropped (s)
    window: int = 3  # the pursuer aims this many cells down the path

    def __post_init__(self):
        check_tuning(self, positive=("cell", "stale_time", "distance_scale"), integers=("relax_passes", "window"))


class CoverageMap:
    """Free/blocked/seen grids and path lengths for W worlds x N pursuers (see module docstring)."""

    def __init__(self, n_worlds: int, n_pursuers: int, params: CoverageParams | None = None):
        self.p = params or CoverageParams()
        self.W, self.N = n_worlds, n_pursuers
        self.GX = self.GY = 0
        self._alloc(8, 8)
        self.goal = np.full((n_worlds, n_pursuers, 2), -1, np.int64)  # goal cell (i, j), -1 none
        self.waited = np.zeros((n_worlds, n_pursuers))  # s the current goal's path has not reached us

    def _alloc(self, gx: int, gy: int) -> None:
        """(Re)allocate to gx x gy cells, keeping what is known."""
        old = {k: getattr(self, k) for k in ("free", "blocked", "seen", "dist")} if self.GX else None
        shape = (self.W, self.N, gx, gy)
        self.free = np.zeros(shape, bool)
        self.blocked = np.zeros(shape, bool)
        self.seen = np.full(shape, -np.inf, np.float32)  # s (episode time) a cell was last seen
        self.dist = np.full(shape, np.inf, np.float32)  # path length to the goal, in cells
        if old:
            for k, v in old.items():
                getattr(self, k)[:, :, : self.GX, : self.GY] = v
        self.GX, self.GY = gx, gy
        c = self.p.cell
        self.centers = np.stack(np.meshgrid((np.arange(gx) + 0.5) * c, (np.arange(gy) + 0.5) * c, indexing="ij"), -1)

    def _dist2(self, xy: np.ndarray) -> np.ndarray:
        """Squared distances (..., GX, GY) m^2 from points xy (..., 2) to every cell centre."""
        c = self.p.cell
        dx = (np.arange(self.GX) + 0.5) * c - xy[..., 0, None]
        dy = (np.arange(self.GY) + 0.5) * c - xy[..., 1, None]
        return dx[..., :, None] ** 2 + dy[..., None, :] ** 2

    def _near_mates(self, mate_pos: np.ndarray, mate_vis: np.ndarray, radius: float) -> np.ndarray:
        """(W, N, GX, GY) bool: cells within radius (m) of a visible teammate."""
        if mate_pos.shape[2] == 0:
            return np.zeros(self.free.shape, bool)
        return ((self._dist2(mate_pos) < radius**2) & mate_vis[..., None, None]).any(2)

    def reset(self, world_ids: np.ndarray) -> None:
        for a, v in ((self.free, False), (self.blocked, False), (self.seen, -np.inf), (self.dist, np.inf)):
            a[world_ids] = v
        self.goal[world_ids] = -1
        self.waited[world_ids] = 0.0

    def _cells(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ij = np.floor(xy / self.p.cell).astype(np.int64)
        return np.clip(ij[..., 0], 0, self.GX - 1), np.clip(ij[..., 1], 0, self.GY - 1)

    def _grow(self, xy: np.ndarray) -> None:
        top = np.floor(np.max(xy.reshape(-1, 2), axis=0) / self.p.cell).astype(np.int64) + 3
        if top[0] > self.GX or top[1] > self.GY:
            self._alloc(max(self.GX, int(top[0]) + 5), max(self.GY, int(top[1]) + 5))

    # ------------------------------------------------------------------ sensing

    def update(self, pos: np.ndarray, rays: np.ndarray, ray_dirs: np.ndarray, ray_range: float,
               mate_pos: np.ndarray, mate_vis: np.ndarray, now: np.ndarray, see_radius: float) -> None:
        """Mark what each pursuer sees now.

        pos (W, N, 2) m; rays (W, N, K) m along ray_dirs (K, 2), capped at ray_range;
        mate_pos (W, N, T, 2) m absolute and mate_vis (W, N, T) bool; now (W,) s episode time.
        """
        W, N = pos.shape[:2]
        step = self.p.cell / 2
        s = (np.arange(int(np.ceil(ray_range / step))) + 0.5) * step  # (S,) m along a ray
        ends = pos[:, :, None] + rays[..., None] * ray_dirs  # (W, N, K, 2)
        self._grow(np.concatenate([pos.reshape(-1, 2), ends.reshape(-1, 2)]))
        pts = pos[:, :, None, None] + s[:, None] * ray_dirs[:, None]  # (W, N, K, S, 2)
        free = s < rays[..., None] - 0.5 * self.p.cell
        # all round even under a narrower field of view: marking only the cells inside the view
        # was level with this on the hard preset (docs/experiments.md section 6, 2026-12-07)
        seen = free & (s < see_radius)
        w = np.broadcast_to(np.arange(W)[:, None, None, None], free.shape)
        n = np.broadcast_to(np.arange(N)[None, :, None, None], free.shape)
        i, j = self._cells(pts)
        self.free[w[free], n[free], i[free], j[free]] = True
        t = np.broadcast_to(now[:, None, None, None], free.shape)
        self.seen[w[seen], n[seen], i[seen], j[seen]] = t[seen]
        hit = rays < ray_range - 1e-6  # (W, N, K): the ray ended on something
        # The cell just past the end is blocked. Past the west and south borders that point is
        # outside the grid and clips into the strip of cells along the border, which is then
        # blocked too (the east and north strips are not: the grid grows there). Known and
        # measured (2026-12-03): blocking only the cell past every border made the team slower,
        # by +17.4 / +30.0 / +2.9 / +10.3 mean steps on layouts 0-3 (paired, 64 episodes, point
        # fidelity, intervals +-23 to +-33): the blocked strip works as a wall margin for the
        # sweep. Changing it changes the baseline every result here is measured against, so it
        # stays until the sweep keeps an explicit margin along every wall.
        hi, hj = self._cells(ends + 0.02 * ray_dirs)
        wk = np.broadcast_to(np.arange(W)[:, None, None], hit.shape)
        nk = np.broadcast_to(np.arange(N)[None, :, None], hit.shape)
        self.blocked[wk[hit], nk[hit], hi[hit], hj[hit]] = True
        pi, pj = self._cells(pos)
        wn = np.arange(W)[:, None], np.arange(N)[None, :]
        self.free[wn[0], wn[1], pi, pj] = True
        self.blocked[wn[0], wn[1], pi, pj] = False
        self.seen[wn[0], wn[1], pi, pj] = np.broadcast_to(now[:, None], (W, N))
        if mate_pos.shape[2]:
            near = self._near_mates(mate_pos, mate_vis, self.p.mate_radius) & self.free
            self.seen = np.where(near, now[:, None, None, None].astype(np.float32), self.seen)

    # ------------------------------------------------------------------ planning

    def choose_goal(self, pos: np.ndarray, mate_pos: np.ndarray, mate_vis: np.ndarray, now: np.ndarray, dt: float) -> None:
        """Pick each pursuer's goal cell: stalest free cell, nearer is better, away from teammates.

        pos (W, N, 2) m, layout frame; mate_pos (W, N, T, 2) m absolute, where each pursuer
        believes its T teammates are, and mate_vis (W, N, T) bool, which of them it knows (as
        in `update`); now (W,) s, each world's episode time; dt (s) the decision step.
        """
        p = self.p
        stale = np.clip((now[:, None, None, None] - self.seen) / p.stale_time, 0.0, 1.0)
        score = stale - np.sqrt(self._dist2(pos)) / p.distance_scale
        if mate_pos.shape[2]:
            score -= p.mate_penalty * self._near_mates(mate_pos, mate_vis, 2 * p.mate_radius)
        has = self.goal[..., 0] >= 0
        gi, gj = np.maximum(self.goal[..., 0], 0), np.maximum(self.goal[..., 1], 0)
        wn = np.arange(self.W)[:, None], np.arange(self.N)[None, :]
        score[wn[0], wn[1], gi, gj] += p.keep_bonus * has
        score = np.where(self.free & ~self.blocked, score, -np.inf).reshape(self.W, self.N, -1)
        best = np.argmax(score, axis=-1)
        new = np.stack([best // self.GY, best % self.GY], -1)
        changed = (new != self.goal).any(-1)
        self.goal = new
        self.waited = np.where(changed, 0.0, self.waited + dt)
        w, n = np.nonzero(changed)
        self.dist[w, n] = np.inf
        self.dist[w, n, new[w, n, 0], new[w, n, 1]] = 0.0

    def _relax(self) -> None:
        """A few passes of the wavefront: path length to the goal, cells beside obstacles costing more."""
        passable = self.free & ~self.blocked
        pad = np.pad(self.blocked, ((0, 0), (0, 0), (1, 1), (1, 1)))
        near = np.zeros_like(self.blocked)
        for di in (-1, 0, 1):
            for dj in (-1, 0, 1):
                near |= pad[:, :, 1 + di : 1 + di + self.GX, 1 + dj : 1 + dj + self.GY]
        cost = (1.0 + self.p.wall_cost * near).astype(np.float32)
        d = self.dist
        for _ in range(self.p.relax_passes):
            pad = np.pad(d, ((0, 0), (0, 0), (1, 1), (1, 1)), constant_values=np.inf)
            best = d
            for di, dj in _OFFSETS:
                best = np.minimum(best, pad[:, :, 1 + di : 1 + di + self.GX, 1 + dj : 1 + dj + self.GY] + cost)
            d = np.where(passable, best, d)
        self.dist = d

    def waypoint(self, pos: np.ndarray, now: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(aim (W, N, 2) m relative, planned (W, N) bool): a few cells down the path to the goal.

        From the pursuer's cell it descends the path length `window` times to the lowest
        4-neighbour and aims at the cell reached. Not planned where the path has not reached
        the pursuer yet (the caller steers straight at the goal meanwhile); a goal not
        reached within `patience` is marked seen, with its surroundings, so that the next
        choice goes elsewhere.
        """
        self._relax()
        W, N = pos.shape[:2]
        w, n = np.arange(W)[:, None], np.arange(N)[None, :]
        ci, cj = self._cells(pos)
        planned = np.isfinite(self.dist[w, n, ci, cj])
        pad = np.pad(self.dist, ((0, 0), (0, 0), (1, 1), (1, 1)), constant_values=np.inf)
        steps = np.array(((0, 0),) + _OFFSETS)  # staying put wins ties
        for _ in range(self.p.window):
            cand = pad[w[..., None], n[..., None], ci[..., None] + 1 + steps[:, 0], cj[..., None] + 1 + steps[:, 1]]
            k = np.argmin(cand, -1)
            ci = np.clip(ci + steps[k, 0], 0, self.GX - 1)
            cj = np.clip(cj + steps[k, 1], 0, self.GY - 1)
        goal_xy = self.centers[self.goal[..., 0], self.goal[..., 1]]
        aim = np.where(planned[..., None], self.centers[ci, cj], goal_xy) - pos
        self.waited = np.where(planned, 0.0, self.waited)
        give_up = self.waited > self.p.patience
        if give_up.any():  # rarely: the 25 writes cost 0.2-0.4 ms a step when nobody gives up
            gw, gn = np.nonzero(give_up)
            r = 2
            for di in range(-r, r + 1):  # the goal's neighbourhood, so that the next goal is elsewhere
                for dj in range(-r, r + 1):
                    gi = np.clip(self.goal[gw, gn, 0] + di, 0, self.GX - 1)
                    gj = np.clip(self.goal[gw, gn, 1] + dj, 0, self.GY - 1)
                    self.seen[gw, gn, gi, gj] = now[gw]
            self.waited[give_up] = 0.0
        return aim, planned
