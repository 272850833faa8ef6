"""Measure the lab -> layout transform: put drones at known layout spots, read where the lab sees them, fit.

    pursuit-mj fly align --flight lab.yaml --spots "0.5,0.5 3.1,0.5 1.8,4.5"

needs a shared positioning system (Lighthouse or Loco): flow-deck estimates start at each
drone's own spot and say nothing about the lab. The drones sit on the floor at the spots
(one spot per drone, in flight-file order); their estimates are averaged over a short
window, and a least-squares similarity (origin, yaw, scale) is fitted (frames.fit_similarity).
"""

from __future__ import annotations

import math
import os
import time
from pathlib import Path
from typing import Sequence

import numpy as np
import yaml

from ..config import DRONE_CONTACT_DISTANCE
from ..configio import ConfigError, load_yaml
from ..geometry import inside_boundary
from ..io_utils import atomic_write_text
from ..layout import Layout, is_index_text
from .board import StateBoard
from .frames import Fit, fit_similarity
from .links import CrazyflieFactory, LinkSet
from .spec import LAB_EXTENT, SCALE_RANGE, FlightSpec, drone_names


def parse_points(text: str, source: str) -> np.ndarray:
    """'x,y x,y ...' (spaces or semicolons between points) -> (K, 2) m, each coordinate within
    LAB_EXTENT of the origin (the fit squares them: 1e308 would overflow)."""
    points = []
    for item in text.replace(";", " ").split():
        parts = item.split(",")
        try:
            if len(parts) != 2:
                raise ValueError
            point = [float(parts[0]), float(parts[1])]
            if not all(math.isfinite(v) for v in point):
                raise ValueError
        except ValueError:
            raise ValueError(f"{source}: '{item}' is not a point x,y (metres)") from None
        far = max(point, key=abs)
        if abs(far) > LAB_EXTENT:
            raise ValueError(f"{source}: '{item}': {far:g} m is farther than {LAB_EXTENT:g} m from the origin: no flight "
                             f"space is that big (points are metres)")
        points.append(point)
    if not points:
        raise ValueError(f"{source}: no points given")
    return np.array(points)


def measure_lab_positions(spec: FlightSpec, uris: Sequence[str] | None = None, factory: CrazyflieFactory | None = None,
                          window: float = 1.0) -> np.ndarray:
    """(D, 2) m: each drone's estimated position averaged over `window` s, flight-file order.

    Shared positioning systems estimate in the lab frame itself. The window begins once every
    drone's Kalman position variance is below safety.estimator_variance (within
    safety.estimator_timeout s; else ValueError naming the drone), and a drone whose variance
    rises above it during the window is refused too: an estimate without a position fix (no
    base station or anchor in sight, not converged yet) says nothing of where the drone
    stands. uris: other links for the same drones (virtual ones), flight-file order.
    """
    if spec.positioning == "flow":
        raise ValueError(f"{spec.source}: align needs Lighthouse or Loco positioning; flow-deck estimates "
                         "start at each drone's own spot (measure the transform with a tape instead)")
    names = drone_names(spec)
    uris = list(uris) if uris is not None else [d.uri for d in spec.drones]
    board = StateBoard(len(names))
    sums = np.zeros((len(names), 2))
    counts = np.zeros(len(names))
    with LinkSet(names, uris, board, factory, spec.safety.connect_timeout) as links:
        for link in links:
            link.start_logs(0.02, 0.1)
        limits = spec.safety
        _wait_fixed(board, names, uris, limits.estimator_variance, time.monotonic() + limits.estimator_timeout, limits.estimator_timeout)
        seen = board.snapshot().state_count.copy()
        end = time.monotonic() + window
        while time.monotonic() < end:
            snap = board.snapshot()
            _wait_fixed(board, names, uris, limits.estimator_variance, 0.0, window, snap)
            new = snap.state_count > seen
            sums[new] += snap.pos[new, :2]
            counts[new] += 1
            seen = snap.state_count
            time.sleep(0.02)
        if (counts == 0).any():
            _refuse_silent(board.snapshot(), int(np.flatnonzero(counts == 0)[0]), names, uris, window)
    return sums / counts[:, None]


def _refuse_silent(snap, i: int, names: Sequence[str], uris: Sequence[str], window: float) -> None:
    """ValueError for drone i, which sent no position during the `window` s measuring window
    (ended at snap.now) although its estimator had settled: says whether cflib reported its link
    lost (and why), nothing at all came from it, or only its state-estimate log stopped, and
    what to check."""
    if snap.lost[i]:
        why = f"cflib reported its link lost ({snap.lost_reason[i]})"
    elif snap.silence[i] >= window:
        why = "nothing at all came from it in that time (link down, or the drone off)"
    else:
        why = "its other packets came but its state-estimate log stopped"
    raise ValueError(f"drone {names[i]} ({uris[i]}) sent no position during the {window:g} s measuring window (--window): {why}; "
                     f"check its battery and radio (channel, range, other radios nearby), then run align again")


def _wait_fixed(board: StateBoard, names: Sequence[str], uris: Sequence[str], limit: float, deadline: float, waited: float,
                snap=None) -> None:
    """Wait until monotonic `deadline` s for every drone's latest Kalman position variances
    (m^2) to be below `limit`; ValueError naming the first drone that is not (`waited` s: how
    long that was, for the message). With `snap` given, judge that snapshot at once (a drone
    that lost its fix during the averaging window)."""
    waiting = snap is None  # before the window, else within it
    while True:
        snap = snap if snap is not None else board.snapshot()
        var = snap.var[:, -1, :]
        fixed = np.isfinite(var).all(axis=-1) & (var < limit).all(axis=-1)
        if fixed.all():
            return
        if time.monotonic() >= deadline:
            i = int(np.flatnonzero(~fixed)[0])
            shown = (f"Kalman variances {np.round(var[i], 5).tolist()} m^2" if np.isfinite(var[i]).all()
                     else "no Kalman variances received")
            when = f"did not settle within {waited:g} s" if waiting else f"lost its fix during the {waited:g} s window"
            raise ValueError(f"drone {names[i]} ({uris[i]}): its position estimate {when} ({shown}, above "
                             f"safety.estimator_variance {limit:g}): are the base stations or anchors in sight, the drone at rest?")
        snap = None
        time.sleep(0.02)


def fit_transform(lab: np.ndarray, spots: np.ndarray, source: str = "--spots", lab_source: str = "the measured lab positions",
                  names: Sequence[str] | None = None) -> Fit:
    """The similarity transform lab -> layout frame from matched points: lab (D, 2) m, where
    the drones stand in the lab frame (their position estimates), and spots (D, 2) m, where the
    flight file says they stand in the layout frame, in the same (flight-file) order. Errors
    name `source` (the spots) or `lab_source` (the lab points), whichever is at fault, and the
    drones by `names` (flight-file order; default: their index). A fit whose scale is outside
    spec.SCALE_RANGE, which no flight file takes, is refused: one side is not in metres."""
    if len(lab) != len(spots):
        raise ValueError(f"{source}: {len(spots)} spots for {len(lab)} drones (one spot per drone, flight-file order)")
    if len(lab) >= 2 and float(((lab - lab.mean(0)) ** 2).sum()) < 1e-8:
        raise ValueError(f"{lab_source}: the lab positions coincide; are the drones at their spots, a few centimetres apart at least?")
    _check_apart(lab, lab_source, names)
    fit = fit_similarity(lab, spots, source)
    _check_scale(fit.transform.scale, source, lab_source)
    _check_spots_apart(spots, fit.transform.scale, source, names)
    return fit


def _label(names: Sequence[str] | None, k: int) -> str:
    return names[k] if names is not None else f"#{k}"


def _check_spots_apart(spots: np.ndarray, scale: float, source: str, names: Sequence[str] | None) -> None:
    """Refuse spots (K, 2) layout m of two drones that lie closer than DRONE_CONTACT_DISTANCE in the
    lab under the fitted `scale` (layout m per lab m): no two Crazyflies stand there (a spot typed twice)."""
    if len(spots) < 2:
        return
    d = np.where(np.eye(len(spots), dtype=bool), np.inf, np.linalg.norm(spots[:, None] - spots[None], axis=-1))
    i, j = sorted(np.unravel_index(np.argmin(d), d.shape))
    if d[i, j] / scale < DRONE_CONTACT_DISTANCE:
        raise ValueError(f"{source}: drones {_label(names, i)} and {_label(names, j)} have spots {d[i, j]:.3f} m apart "
                         f"({d[i, j] / scale:.3f} m in the lab), closer than two Crazyflies can stand ({DRONE_CONTACT_DISTANCE:g} m): "
                         f"one spot per drone, flight-file order")


def check_spots_in_arena(spots: np.ndarray, layout: Layout, source: str = "--spots", names: Sequence[str] | None = None) -> None:
    """Refuse spots (K, 2) m outside the arena of `layout`: the drones stand inside it, and spots
    are layout metres from the arena's lower-left corner (spots in cm lie far outside). Errors
    name `source` and the drone by `names` (flight-file order)."""
    outside = ~inside_boundary(layout, np.asarray(spots, np.float64))
    if outside.any():
        k = int(np.flatnonzero(outside)[0])
        raise ValueError(f"{source}: drone {_label(names, k)}'s spot [{spots[k][0]:g}, {spots[k][1]:g}] is outside the "
                         f"{layout.width:g} x {layout.height:g} m arena of {layout.source}: spots are where the drones stand, in "
                         f"layout metres from the arena's lower-left corner")


def _check_scale(scale: float, source: str, lab_source: str) -> None:
    """Refuse a fitted scale (layout m per lab m) that no flight file takes (spec.SCALE_RANGE):
    the spots and the lab positions are not both in metres."""
    lo, hi = SCALE_RANGE
    if not lo <= scale <= hi:
        raise ValueError(f"{source} and {lab_source}: they fit with a scale of {scale:.4g} layout m per lab m, outside the "
                         f"{lo:g} to {hi:g} a flight file takes (transform.scale): are both in metres? (a scale near 100 or "
                         f"0.01 is one side in cm, near 1000 or 0.001 one side in mm)")


def _check_apart(lab: np.ndarray, lab_source: str, names: Sequence[str] | None) -> None:
    """Refuse lab positions (D, 2) m of two drones closer than DRONE_CONTACT_DISTANCE: two
    Crazyflies cannot stand there (one drone read twice, or one not at its spot), and points
    that close leave the fitted yaw to the measurement noise."""
    if len(lab) < 2:
        return
    d = np.where(np.eye(len(lab), dtype=bool), np.inf, np.linalg.norm(lab[:, None] - lab[None], axis=-1))
    i, j = np.unravel_index(np.argmin(d), d.shape)
    if d[i, j] < DRONE_CONTACT_DISTANCE:
        label = list(names) if names is not None else [f"#{k}" for k in range(len(lab))]
        raise ValueError(f"{lab_source}: drones {label[min(i, j)]} and {label[max(i, j)]} stand {d[i, j]:.3f} m apart in the lab, "
                         f"closer than two Crazyflies can ({DRONE_CONTACT_DISTANCE:g} m): is each drone on its own spot?")


def spot_turns(spots: np.ndarray, tol: float) -> list[int]:
    """Turns about their centre (whole degrees in (0, 360), ascending) that carry the spots
    (K, 2) m onto themselves, each spot within `tol` m of another's: drones standing each on
    another's spot so turned fit exactly as well as on their own, with the fitted transform
    turned by as much (corners of a rectangle: [180]; a square: [90, 180, 270]). Empty for
    fewer than three spots (two always fit: warned about on their own) or a lopsided placement."""
    z = np.asarray(spots, np.float64) @ np.array([1.0, 1j])  # as complex numbers
    if len(z) < 3:
        return []
    z = z - z.mean()
    ref = int(np.argmax(np.abs(z)))  # a spot off the centre: its image fixes the turn
    turns = set()
    for j in np.flatnonzero(np.abs(np.abs(z) - np.abs(z[ref])) <= tol):
        if j == ref:
            continue
        turned = z * (z[j] / z[ref]) / abs(z[j] / z[ref])
        near = np.abs(turned[:, None] - z[None]) <= tol
        if near.any(axis=1).all() and near.any(axis=0).all():
            turns.add(round(math.degrees(np.angle(z[j] / z[ref]))) % 360)
    return sorted(turns - {0})


def transform_yaml(fit: Fit) -> str:
    t = fit.transform
    return yaml.safe_dump({"transform": {"origin": [round(t.origin[0], 5), round(t.origin[1], 5)], "yaw": round(t.yaw, 6), "scale": round(t.scale, 6)}}, sort_keys=False, default_flow_style=None)


def write_with_transform(spec: FlightSpec, fit: Fit, out: str | Path, overrides: Sequence[str] = ()) -> Path:
    """A copy of the flight file with the measured transform (comments are not kept), written
    only if the flight still resolves with it: the arena in the lab, every start in the arena
    and clear of its obstacles (what `fly check` checks, with the same --set overrides). A
    layout file kept beside the flight file is referred to from the copy's folder."""
    data = load_yaml(spec.source)
    data["transform"] = yaml.safe_load(transform_yaml(fit))["transform"]
    beside = _layout_beside(spec)
    from .plan import resolve_flight
    from .spec import flight_from_dict

    try:
        resolve_flight(flight_from_dict({**data, "layout": str(beside) if beside else spec.layout}, str(out)), overrides)
    except ConfigError as exc:
        raise ValueError(f"the measured transform does not make a valid flight: {exc}") from None
    if beside is not None:  # the copy finds it wherever it is written
        data["layout"] = Path(os.path.relpath(beside, Path(out).parent.resolve())).as_posix()
    return atomic_write_text(out, yaml.safe_dump(data, sort_keys=False, default_flow_style=None))


def _layout_beside(spec: FlightSpec) -> Path | None:
    """The absolute path of the flight's layout file when it is found beside the flight file
    (plan.resolve_flight's rule), else None (a built-in index, or a path read as given)."""
    ref = spec.layout
    if not isinstance(ref, str) or is_index_text(ref) or Path(ref).is_file():
        return None
    beside = Path(spec.source).parent / ref
    return beside.resolve() if beside.is_file() else None


def align(spec: FlightSpec, spots: Sequence[Sequence[float]], lab: Sequence[Sequence[float]] | None = None,
          uris: Sequence[str] | None = None, factory: CrazyflieFactory | None = None, window: float = 1.0) -> tuple[Fit, np.ndarray]:
    """Fit the transform from spots (K, 2) m layout and lab positions (K, 2) m (measured if not given).
    Spots outside the flight's arena are refused before any drone is measured."""
    from .plan import resolve_layout

    spots = np.asarray(spots, np.float64)
    check_spots_in_arena(spots, resolve_layout(spec), names=drone_names(spec))  # before any radio: a typo costs no measuring
    lab_pts = np.asarray(lab, np.float64) if lab is not None else measure_lab_positions(spec, uris, factory, window)
    return fit_transform(lab_pts, spots, lab_source="--lab" if lab is not None else "the measured lab positions",
                         names=drone_names(spec)), lab_pts
