"""Planar vector maths shared by the escape model, the shield, the heuristic team and flight safety.

Vectors are (..., 2) arrays, x then y, in whatever frame and unit the caller works in (m or
m/s); the small helpers broadcast over the leading dimensions, `limit_closing` takes arrays
whose leading dimensions already agree.

`limit_closing` is the one closing-speed limiter of the project: the safety shield caps a
pursuer's speed toward walls, teammates and caught evaders with it, and flight safety caps
real drones' speeds toward each other and the fence.
"""

from __future__ import annotations

import numpy as np

EPS = 1e-9  # lengths below this have no direction
_SLACK = 1e-7  # a velocity within this much of a cap (m/s) keeps it (rounding)


def norm(v: np.ndarray) -> np.ndarray:
    """Length (...) of vectors v (..., 2)."""
    return np.hypot(v[..., 0], v[..., 1])


def dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Dot product (...) of vectors a, b (..., 2), broadcast."""
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1]


def unit(v: np.ndarray, fallback: np.ndarray | float = 0.0) -> np.ndarray:
    """v (..., 2) scaled to unit length; `fallback` (broadcastable) where |v| is ~0."""
    n = norm(v)[..., None]
    return np.where(n > EPS, v / np.maximum(n, EPS), fallback)


def perp(v: np.ndarray) -> np.ndarray:
    """v (..., 2) rotated by +90 degrees."""
    return np.stack([-v[..., 1], v[..., 0]], -1)


def rotate(v: np.ndarray, angle: np.ndarray | float) -> np.ndarray:
    """v (..., 2) rotated counter-clockwise by angle (...) or a scalar, rad."""
    c, s = np.cos(angle), np.sin(angle)
    return np.stack([c * v[..., 0] - s * v[..., 1], s * v[..., 0] + c * v[..., 1]], -1)


def clip_norm(v: np.ndarray, max_norm: np.ndarray | float) -> np.ndarray:
    """v (..., 2) scaled down to at most max_norm (...) or a scalar, direction kept."""
    scale = np.minimum(1.0, max_norm / np.maximum(norm(v), 1e-12))
    return v * np.asarray(scale)[..., None]


def clip_unit(a: np.ndarray) -> np.ndarray:
    """a (..., 2) scaled down to at most unit length (so both axes lie in [-1, 1]). A vector
    this returned comes back unchanged, bit for bit (a policy's actions are clipped again by
    whatever wraps it)."""
    return a / np.maximum(np.linalg.norm(a, axis=-1, keepdims=True), 1.0)


def limit_closing(v: np.ndarray, u: np.ndarray, cap: np.ndarray, passes: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """Velocities (..., 2) near v (..., 2) whose component along every hazard direction u
    (..., H, 2) (unit vectors; zero ones are ignored) is at most cap (..., H) (negative: move
    away; inf: no limit), and whether every cap holds (...) bool.

    First `passes` projections, each onto the cap exceeded most: where one cap binds, that is
    the nearest allowed velocity. Where two caps meet at a sharp angle (a wall and a teammate
    on either side) projections approach an answer only slowly (four passes left 0.05 m/s
    toward the teammate), so rows still exceeding a cap are solved again: in the plane the
    nearest allowed velocity is v itself, v moved onto one cap's line, or the crossing of two
    lines, and these candidates are tried for the caps the passes picked plus up to three
    more (the one exceeded most each time); the nearest allowed candidate is taken. That keeps
    every cap, but with many caps it is not always the nearest allowed velocity overall (a
    review found one 1.18 m/s from v where 1.12 was possible). Where no candidate keeps every
    cap (they conflict), a row keeps the projections' result and is reported False.
    """
    lead = v.shape[:-1]
    if u.shape[-2] == 0:  # no hazards
        return v.copy(), np.ones(lead, bool)
    v2, u2, cap2 = v.reshape(-1, 2), u.reshape(-1, u.shape[-2], 2), cap.reshape(-1, cap.shape[-1])
    cap2 = np.where(np.abs(u2).sum(-1) > EPS, cap2, np.inf)
    passed, binding = _project(v2, u2, cap2, passes)
    exceeded = np.max(np.einsum("phk,pk->ph", u2, passed) - cap2, axis=-1, initial=-np.inf) > _SLACK  # (P,)
    if not exceeded.any():
        return passed.reshape(v.shape), np.ones(lead, bool)
    rows = np.flatnonzero(exceeded)
    exact = _closest_allowed(v2[rows], u2[rows], cap2[rows], binding[rows])
    solved = ~np.isnan(exact[:, 0])
    out = passed.copy()
    out[rows[solved]] = exact[solved]
    met = np.ones(len(v2), bool)
    met[rows[~solved]] = False
    return out.reshape(v.shape), met.reshape(lead)


def _project(v: np.ndarray, u: np.ndarray, cap: np.ndarray, passes: int) -> tuple[np.ndarray, np.ndarray]:
    """v (P, 2) with its component along u (P, H, 2) cut to cap (P, H), one cap per pass,
    the one exceeded most first; also the caps (P, passes + 1) the passes picked and the one
    exceeded most at the end (hazard indices)."""
    picked = []
    rows = np.arange(len(v))
    for i in range(passes + 1):
        excess = np.einsum("phk,pk->ph", u, v) - cap
        worst = np.argmax(excess, axis=-1)
        picked.append(worst)
        if i == passes:
            break
        v = v - np.maximum(excess[rows, worst], 0.0)[:, None] * u[rows, worst]
    return v, np.stack(picked, -1)


def _closest_allowed(v: np.ndarray, u: np.ndarray, cap: np.ndarray, binding: np.ndarray, rounds: int = 3) -> np.ndarray:
    """The velocity (P, 2) nearest to v (P, 2) within every cap (u (P, H, 2), cap (P, H)),
    searched among the caps `binding` (P, B hazard indices) and, for `rounds` more tries, the
    cap most exceeded by the best candidate; NaN rows where none is found.

    Each row is solved on its own: a row that has an allowed candidate keeps it, whatever the
    other rows still need (so a pursuer's velocity does not depend on the rest of the batch)."""
    out = np.full(v.shape, np.nan)
    todo = np.arange(len(v))  # rows not solved yet
    for r in range(rounds + 1):
        vt, ut, ct = v[todo], u[todo], cap[todo]
        rows = np.arange(len(todo))
        candidates = _candidates(vt, ut, ct, binding)  # (T, C, 2)
        with np.errstate(invalid="ignore"):
            over = np.einsum("pck,phk->pch", candidates, ut) - ct[:, None]  # (T, C, H)
            worst = np.where(np.isfinite(candidates).all(-1), over.max(-1, initial=-np.inf), np.inf)  # (T, C)
        allowed = worst <= _SLACK
        found = allowed.any(-1)
        moved = np.where(allowed, np.sum((candidates - vt[:, None]) ** 2, axis=-1), np.inf)
        chosen = candidates[rows, np.argmin(moved, axis=-1)]
        out[todo[found]] = chosen[found]
        if found.all() or r == rounds:
            break
        left = ~found
        least = np.argmin(worst[left], axis=-1)  # the candidate closest to allowed
        exceeded = np.nan_to_num(over[left][np.arange(left.sum()), least], nan=-np.inf)  # (T', H)
        binding = binding[left]
        exceeded[np.arange(len(binding))[:, None], binding] = -np.inf  # a cap already in the set adds nothing
        binding = np.concatenate([binding, np.argmax(exceeded, axis=-1)[:, None]], axis=-1)
        todo = todo[left]
    return out


def _candidates(v: np.ndarray, u: np.ndarray, cap: np.ndarray, binding: np.ndarray) -> np.ndarray:
    """Velocities (P, C, 2) where the nearest allowed one can lie if only the caps `binding`
    (P, B) bind: v, v moved onto each cap's line, each crossing of two lines (NaN where two
    lines are parallel or a cap is infinite)."""
    rows = np.arange(len(v))[:, None]
    ub, cb = u[rows, binding], cap[rows, binding]  # (P, B, 2), (P, B)
    i, j = np.triu_indices(binding.shape[-1], k=1)
    ui, uj, ci, cj = ub[:, i], ub[:, j], cb[:, i], cb[:, j]
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        onto_one = v[:, None] - (np.einsum("pbk,pk->pb", ub, v) - cb)[..., None] * ub
        det = ui[..., 0] * uj[..., 1] - ui[..., 1] * uj[..., 0]
        det = np.where(np.abs(det) > EPS, det, np.nan)
        crossing = np.stack([(ci * uj[..., 1] - cj * ui[..., 1]) / det, (ui[..., 0] * cj - uj[..., 0] * ci) / det], -1)
    return np.concatenate([v[:, None], onto_one, crossing], axis=1)
