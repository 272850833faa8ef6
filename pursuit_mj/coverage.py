"""A per-pursuer coverage map built from range readings: where to sweep next, and a path there.

No map is given: each pursuer builds its own grid in the layout frame (origin at the arena's
lower-left corner, `cell` m cells; the grid grows when a reading lands beyond it). From its
rays it marks cells a ray crossed as *free*, cells where a ray ended on something as
*blocked*, and cells within `see_radius` along a ray as *seen now*; cells near a visible
teammate count as seen too (the teammate looks there). The sweep goal is the free cell
unseen for longest, traded against distance; a wavefront (4-connected, a few relaxation
passes per step) spreads the path length to the goal over passable cells (cells beside
obstacles cost more, so paths keep to wide passages), and the pursuer follows it down. Arrays are (W, N, GX, GY).

Cost: per step the map touches the cells along the rays, around visible teammates, inside the
box around what the pursuers have found free (scoring the goal), and the cells whose path
length can change (the wavefront's front, the cells whose passability or wall cost changed,
and the neighbours of a new goal), not the whole grid, which keeps what earlier episodes
found. The results are those of relaxing every cell of the grid, to the bit (tests/test_heuristic.py).
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
        self._front = np.zeros(0, np.int64)  # flat cells whose path length may change in the next pass
        self._alloc(8, 8)
        # per world, the lowest and highest cell indices (i, j) its free cells may have (see _box)
        self._box_lo = np.full((n_worlds, 2), np.iinfo(np.int64).max)
        self._box_hi = np.full((n_worlds, 2), -1, np.int64)
        self.goal = np.full((n_worlds, n_pursuers, 2), -1, np.int64)  # goal cell (i, j), -1 none
        self.waited = np.zeros((n_worlds, n_pursuers))  # s the current goal's path has not reached us

    def _alloc(self, gx: int, gy: int) -> None:
        """(Re)allocate to gx x gy cells, keeping what is known.

        free, blocked, seen and dist are views into arrays with a border of one cell around the
        grid (never free, never blocked, never seen, infinitely far), so that cells are marked by
        flat index and the wavefront reads a cell's neighbours without bounds checks; _cost_p
        holds each cell's step cost in the same layout."""
        old = {k: getattr(self, k) for k in ("_free_p", "_blocked_p", "_seen_p", "_dist_p", "_cost_p")} if self.GX else None
        padded = (self.W, self.N, gx + 2, gy + 2)
        self._free_p = np.zeros(padded, bool)
        self._blocked_p = np.zeros(padded, bool)
        self._dist_p = np.full(padded, np.inf, np.float32)  # path length to the goal, in cells
        self._seen_p = np.full(padded, -np.inf, np.float32)  # s (episode time) a cell was last seen
        self._cost_p = np.full(padded, 1.0, np.float32)  # step cost: 1, 1 + wall_cost beside a blocked cell
        if old:
            for k, v in old.items():
                getattr(self, k)[:, :, 1 : self.GX + 1, 1 : self.GY + 1] = v[:, :, 1:-1, 1:-1]
            where = np.unravel_index(self._front, (self.W, self.N, self.GX + 2, self.GY + 2))
            self._front = np.ravel_multi_index(where, padded)
        padded_arrays = (self._free_p, self._blocked_p, self._seen_p, self._dist_p)
        self.free, self.blocked, self.seen, self.dist = (a[:, :, 1:-1, 1:-1] for a in padded_arrays)
        old_gx, old_gy = self.GX, self.GY
        self.GX, self.GY = gx, gy
        # The cells just beyond the old grid were its border, which _note_changes leaves out: one
        # may lie beside a blocked cell of the old last row or column (a hit clipped there in a
        # step whose readings were not all numbers, so that the grid did not grow). The cells
        # further out lie beside new cells only, never blocked.
        if old and gx > old_gx:
            self._renew_costs(old_gx, old_gx + 1, 0, gy)
        if old and gy > old_gy:
            self._renew_costs(0, gx, old_gy, old_gy + 1)
        self._steps = np.array([gy + 2, -(gy + 2), 1, -1])  # flat offsets of _OFFSETS in the padded arrays
        c = self.p.cell
        self.centers = np.stack(np.meshgrid((np.arange(gx) + 0.5) * c, (np.arange(gy) + 0.5) * c, indexing="ij"), -1)

    def _renew_costs(self, i0: int, i1: int, j0: int, j1: int) -> None:
        """Step cost of the grid cells i0 <= i < i1, j0 <= j < j1 from the blocked cells around
        each (1, or 1 + wall_cost beside one)."""
        near = np.zeros((self.W, self.N, i1 - i0, j1 - j0), bool)
        for di in (-1, 0, 1):
            for dj in (-1, 0, 1):
                near |= self._blocked_p[:, :, 1 + i0 + di : 1 + i1 + di, 1 + j0 + dj : 1 + j1 + dj]
        self._cost_p[:, :, 1 + i0 : 1 + i1, 1 + j0 : 1 + j1] = (1.0 + self.p.wall_cost * near).astype(np.float32)

    def _flat(self, w: np.ndarray, n: np.ndarray, i: np.ndarray, j: np.ndarray) -> np.ndarray:
        """Flat indices in the padded arrays of grid cells (w, n, i, j)."""
        return ((w * self.N + n) * (self.GX + 2) + i + 1) * (self.GY + 2) + j + 1

    def _dist2_box(self, xy: np.ndarray, box: tuple[int, int, int, int]) -> np.ndarray:
        """Squared distances (..., I1 - I0, J1 - J0) m^2 from points xy (..., 2) to the cell centres
        of box (I0, I1, J0, J1) (cell index ranges, ends excluded)."""
        c = self.p.cell
        dx = (np.arange(box[0], box[1]) + 0.5) * c - xy[..., 0, None]
        dy = (np.arange(box[2], box[3]) + 0.5) * c - xy[..., 1, None]
        return dx[..., :, None] ** 2 + dy[..., None, :] ** 2

    def _near_mates(self, mate_pos: np.ndarray, mate_vis: np.ndarray, radius: float) -> np.ndarray:
        """Flat indices (padded arrays, repeats possible) of the grid cells of pursuer (w, n) whose
        centre lies within radius (m) of a teammate it sees. Looks at a window of cells around
        each teammate, not at the grid."""
        c = self.p.cell
        W, N = mate_pos.shape[:2]
        r = int(np.ceil(radius / c)) + 1
        off = np.arange(-r, r + 1)
        # far away (or not a number): a window outside the grid, or cells the distance test refuses
        home = np.clip(np.nan_to_num(np.asarray(mate_pos, np.float64) / c), -r - 1, max(self.GX, self.GY) + r + 1)
        home = np.floor(home).astype(np.int64)
        i = home[..., 0, None, None] + off[:, None]  # (W, N, T, 2r+1, 1)
        j = home[..., 1, None, None] + off[None, :]  # (W, N, T, 1, 2r+1)
        dx = (i + 0.5) * c - mate_pos[..., 0, None, None]
        dy = (j + 0.5) * c - mate_pos[..., 1, None, None]
        near = (dx**2 + dy**2 < radius**2) & mate_vis[..., None, None]
        near &= (i >= 0) & (i < self.GX) & (j >= 0) & (j < self.GY)
        w, n = np.arange(W)[:, None, None, None, None], np.arange(N)[None, :, None, None, None]
        return np.broadcast_to(self._flat(w, n, i, j), near.shape)[near]

    def _near_mates_in(self, box: tuple[int, int, int, int], mate_pos: np.ndarray, mate_vis: np.ndarray,
                       radius: float) -> np.ndarray:
        """(W, N, I1 - I0, J1 - J0) bool: the cells of box (I0, I1, J0, J1) whose centre lies within
        radius (m) of a teammate pursuer (w, n) sees. A box no larger than a few teammates'
        windows is tested whole (fewer steps), a larger one through the windows (_near_mates)."""
        i0, i1, j0, j1 = box
        window = 2 * (int(np.ceil(radius / self.p.cell)) + 1) + 1
        if (i1 - i0) * (j1 - j0) <= 4 * window**2:
            return ((self._dist2_box(mate_pos, box) < radius**2) & mate_vis[..., None, None]).any(2)
        f = self._near_mates(mate_pos, mate_vis, radius)
        wn, i, j = f // ((self.GX + 2) * (self.GY + 2)), (f // (self.GY + 2)) % (self.GX + 2) - 1, f % (self.GY + 2) - 1
        inside = (i >= i0) & (i < i1) & (j >= j0) & (j < j1)
        near = np.zeros((self.W, self.N, i1 - i0, j1 - j0), bool)
        near.reshape(-1)[((wn * (i1 - i0) + i - i0) * (j1 - j0) + j - j0)[inside]] = True
        return near

    def reset(self, world_ids: np.ndarray) -> None:
        """Forget what the listed worlds' pursuers found (the grid keeps its size)."""
        for a, v in ((self.free, False), (self.blocked, False), (self.seen, -np.inf), (self.dist, np.inf)):
            a[world_ids] = v
        self._cost_p[world_ids] = 1.0
        self.goal[world_ids] = -1
        self.waited[world_ids] = 0.0
        self._box_lo[world_ids] = np.iinfo(np.int64).max
        self._box_hi[world_ids] = -1

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
        w, n = np.arange(W)[:, None, None, None], np.arange(N)[None, :, None, None]
        cells = self._flat(w, n, *self._cells(pts))  # (W, N, K, S) flat, padded arrays
        hit = rays < ray_range - 1e-6  # (W, N, K): the ray ended on something
        # The cell just past the end is blocked. Past the west and south borders that point is
        # outside the grid and clips into the strip of cells along the border, which is then
        # blocked too (the east and north strips are not: the grid grows there). Known and
        # measured (2026-12-03): blocking only the cell past every border made the team slower,
        # by +17.4 / +30.0 / +2.9 / +10.3 mean steps on layouts 0-3 (paired, 64 episodes, point
        # fidelity, intervals +-23 to +-33): the blocked strip works as a wall margin for the
        # sweep. Changing it changes the baseline every result here is measured against, so it
        # stays until the sweep keeps an explicit margin along every wall.
        ends_cells = self._cells(ends + 0.02 * ray_dirs)
        hits = self._flat(w[..., 0], n[..., 0], *ends_cells)[hit]
        pi, pj = self._cells(pos)
        here = self._flat(w[..., 0, 0], n[..., 0, 0], pi, pj).ravel()  # (W * N,) each pursuer's cell
        now_here = np.broadcast_to(now[:, None], (W, N)).ravel()
        marked = cells[free]
        touched = np.concatenate([marked, hits, here])
        free_p, blocked_p, seen_p = (a.reshape(-1) for a in (self._free_p, self._blocked_p, self._seen_p))
        was_free, was_blocked = free_p[touched], blocked_p[touched]
        free_p[marked] = True
        seen_p[cells[seen]] = np.broadcast_to(now[:, None, None, None], free.shape)[seen]
        blocked_p[hits] = True
        free_p[here] = True
        blocked_p[here] = False
        seen_p[here] = now_here
        self._note_changes(touched, was_free, was_blocked)
        # free cells lie between a pursuer and its rays' ends: the box of those holds them (_box
        # adds a cell of margin all round: `ends` are rounded otherwise than the points on a ray)
        ei, ej = self._cells(ends)
        lo = np.stack([np.minimum(pi, ei.min(-1, initial=pi.max())), np.minimum(pj, ej.min(-1, initial=pj.max()))], -1)
        hi = np.stack([np.maximum(pi, ei.max(-1, initial=0)), np.maximum(pj, ej.max(-1, initial=0))], -1)
        self._box_lo = np.minimum(self._box_lo, lo.min(1))
        self._box_hi = np.maximum(self._box_hi, hi.max(1))
        if mate_pos.shape[2]:
            near = self._near_mates(mate_pos, mate_vis, self.p.mate_radius)
            near = near[free_p[near]]
            seen_p[near] = now[near // (N * (self.GX + 2) * (self.GY + 2))].astype(np.float32)

    def _note_changes(self, touched: np.ndarray, was_free: np.ndarray, was_blocked: np.ndarray) -> None:
        """After the flat cells `touched` (which were free / blocked as given) were marked: renew the
        step cost of the 3 x 3 cells around each cell whose blocked flag changed, and put on the
        wavefront's front the cells whose path length may change now: those that turned free and
        those whose cost was renewed (among them a cleared cell, which may be reached again; a cell
        that turned blocked is no longer relaxed)."""
        new_blocked = self._blocked_p.reshape(-1)[touched] != was_blocked
        new_free = self._free_p.reshape(-1)[touched] != was_free
        ring = (np.arange(-1, 2)[:, None] * (self.GY + 2) + np.arange(-1, 2)[None, :]).ravel()  # 3 x 3 flat offsets
        around = np.unique((touched[new_blocked, None] + ring).ravel())
        i, j = (around // (self.GY + 2)) % (self.GX + 2), around % (self.GY + 2)
        around = around[(i >= 1) & (i <= self.GX) & (j >= 1) & (j <= self.GY)]  # grid cells, not the border
        near = self._blocked_p.reshape(-1)[around[:, None] + ring].any(-1)
        self._cost_p.reshape(-1)[around] = (1.0 + self.p.wall_cost * near).astype(np.float32)
        self._front = np.concatenate([self._front, touched[new_free], around])

    def _box(self) -> tuple[int, int, int, int]:
        """(I0, I1, J0, J1): cell ranges (ends excluded) that hold every free cell of the grid."""
        lo, hi = self._box_lo.min(0), self._box_hi.max(0)
        if hi[0] < 0:  # nothing free anywhere yet
            return 0, 1, 0, 1
        lo, hi = np.maximum(lo - 1, 0), np.minimum(hi + 1, (self.GX - 1, self.GY - 1))
        return int(lo[0]), int(hi[0]) + 1, int(lo[1]), int(hi[1]) + 1

    # ------------------------------------------------------------------ planning

    def choose_goal(self, pos: np.ndarray, mate_pos: np.ndarray, mate_vis: np.ndarray, now: np.ndarray, dt: float) -> None:
        """Pick each pursuer's goal cell: stalest free cell, nearer is better, away from teammates.

        pos (W, N, 2) m, layout frame; mate_pos (W, N, T, 2) m absolute, where each pursuer
        believes its T teammates are, and mate_vis (W, N, T) bool, which of them it knows (as
        in `update`); now (W,) s, each world's episode time; dt (s) the decision step.
        """
        p = self.p
        i0, i1, j0, j1 = box = self._box()  # every candidate (free, not blocked) lies in it
        # score = staleness - distance / distance_scale - mate_penalty near teammates, in place
        score = now[:, None, None, None] - self.seen[:, :, i0:i1, j0:j1]
        score /= p.stale_time
        np.clip(score, 0.0, 1.0, out=score)
        far = self._dist2_box(pos, box)
        np.sqrt(far, out=far)
        far /= p.distance_scale
        score -= far
        if mate_pos.shape[2]:
            np.subtract(score, p.mate_penalty, out=score, where=self._near_mates_in(box, mate_pos, mate_vis, 2 * p.mate_radius))
        has = self.goal[..., 0] >= 0
        gi, gj = np.maximum(self.goal[..., 0], 0), np.maximum(self.goal[..., 1], 0)
        wn = np.arange(self.W)[:, None], np.arange(self.N)[None, :]
        inside = (gi >= i0) & (gi < i1) & (gj >= j0) & (gj < j1)  # a goal outside is no candidate
        score[wn[0], wn[1], np.clip(gi - i0, 0, i1 - i0 - 1), np.clip(gj - j0, 0, j1 - j0 - 1)] += p.keep_bonus * (has & inside)
        np.copyto(score, -np.inf, where=~self.free[:, :, i0:i1, j0:j1] | self.blocked[:, :, i0:i1, j0:j1])  # no candidates
        score = score.reshape(self.W, self.N, -1)
        best = np.argmax(score, axis=-1)
        new = np.stack([i0 + best // (j1 - j0), j0 + best % (j1 - j0)], -1)
        # no candidate at all: the first cell of the grid, as an argmax over it would give
        none = np.take_along_axis(score, best[..., None], -1)[..., 0] == -np.inf
        new[none] = 0
        changed = (new != self.goal).any(-1)
        self.goal = new
        self.waited = np.where(changed, 0.0, self.waited + dt)
        w, n = np.nonzero(changed)
        self.dist[w, n] = np.inf
        self.dist[w, n, new[w, n, 0], new[w, n, 1]] = 0.0
        goals = self._flat(w, n, new[w, n, 0], new[w, n, 1])
        self._front = np.concatenate([self._front, (goals[:, None] + self._steps).ravel()])

    def _relax(self) -> None:
        """A few passes of the wavefront: path length to the goal, cells beside obstacles costing more.

        Each pass gives every passable cell min(its length, a 4-neighbour's length + its cost),
        all from the lengths before the pass; it evaluates only the cells on the front (those
        whose length can change: see `_note_changes` and `choose_goal`), and the cells beside
        the ones it changed make the next front. The same to the bit as a pass over the grid."""
        dist, cost = self._dist_p.reshape(-1), self._cost_p.reshape(-1)
        free, blocked = self._free_p.reshape(-1), self._blocked_p.reshape(-1)
        if not self.p.relax_passes:  # nothing reads the front: keep none (it would grow every step)
            self._front = self._front[:0]
        for _ in range(self.p.relax_passes):
            cells = np.unique(self._front)
            cells = cells[free[cells] & ~blocked[cells]]  # passable (the border is not)
            old = dist[cells]
            best, c = old, cost[cells]
            for step in self._steps:
                best = np.minimum(best, dist[cells + step] + c)
            changed = best != old
            moved = cells[changed]
            dist[moved] = best[changed]
            self._front = (moved[:, None] + self._steps).ravel()

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
        pad = self._dist_p  # infinitely far beyond the grid
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
