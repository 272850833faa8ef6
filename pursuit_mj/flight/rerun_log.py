"""A flight recorded for the rerun viewer (`rerun flight.rrd`), real or virtual.

| entity                         | what (layout frame, m, m/s; V)                                |
|--------------------------------|---------------------------------------------------------------|
| `arena/border`, `arena/obstacles` | the layout's border and virtual obstacles (static)         |
| `arena/fence`                  | the geofence: the border moved in by the margin (static)      |
| `drones/{name}`                | estimated position, labelled, coloured by role                |
| `drones/{name}/velocity`       | estimated velocity arrow                                      |
| `drones/{name}/command`        | commanded velocity arrow (what was sent, after safety)         |
| `battery/{name}`               | battery voltage                                               |
| `height/{name}`                | estimated height                                              |
| `events`                       | every safety and flight event as a text log line              |

Timeline `flight_time`: seconds since the event log opened. The file is written as
`NAME.unfinished-PID-XXXXXX.rrd` and renamed when the recorder closes, even if the flight ended badly;
a process killed mid-flight (kill -9) leaves that file, readable, and the next recording of the
same name says where it is.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import rerun as rr

from ..io_utils import CannotWrite, keep_beside, killed_unfinished, move_into_place, not_replaced_message
from ..recording.unfinished import flush, stream_to_unfinished
from ..layout import Box, Wall
from ..palette import ROLE_RGBA, rgb255
from .plan import FlightPlan

ROLE_RGB = {"pursuer": rgb255(ROLE_RGBA["pursuer"]), "evader": rgb255(ROLE_RGBA["evader"]), "target": (160, 60, 200)}
LEVEL = {"info": "INFO", "warn": "WARN", "error": "ERROR"}


def _outline(o, z: float) -> list[list[float]]:
    if isinstance(o, Wall):
        o = o.as_box()
    if isinstance(o, Box):
        hx, hy = o.size[0] / 2, o.size[1] / 2
        c, s = math.cos(o.yaw), math.sin(o.yaw)
        pts = [(hx, hy), (-hx, hy), (-hx, -hy), (hx, -hy), (hx, hy)]
        return [[o.center[0] + c * x - s * y, o.center[1] + s * x + c * y, z] for x, y in pts]
    a = np.linspace(0, 2 * np.pi, 33)
    return [[o.center[0] + o.radius * math.cos(t), o.center[1] + o.radius * math.sin(t), z] for t in a]


def fence_outline(border: np.ndarray, margin: float) -> np.ndarray | None:
    """The geofence along the border: the border segments (S, 4) (counter-clockwise, inside on the
    left, geometry.boundary_segments) each moved `margin` (m) inwards, joined where they meet, as a
    closed outline (S + 1, 2); None when the margin turns the outline inside out (no room). Exact
    at convex corners; at a reflex corner the fence is an arc around it, drawn as its mitre."""
    seg = np.asarray(border, dtype=np.float64)
    d = seg[:, 2:4] - seg[:, 0:2]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    normal = np.stack([-d[:, 1], d[:, 0]], axis=1)  # inwards: left of each segment
    before = np.roll(normal, 1, axis=0)  # of the segment that ends at each one's start
    corners = seg[:, 0:2] + margin * (normal + before) / (1.0 + np.sum(normal * before, axis=1, keepdims=True))
    moved = corners[(np.arange(len(seg)) + 1) % len(seg)] - corners  # each moved segment, start to end
    if np.any(np.sum(moved * d, axis=1) <= 0.0):  # a segment shorter than its corners cut off: turned around
        return None
    return np.concatenate([corners, corners[:1]])


class FlightRecorder:
    """Streams a flight into an .rrd file (module docstring); `close()` finishes the file."""

    def __init__(self, path: str | Path, plan: FlightPlan):
        self.plan = plan
        self.path = Path(path)
        self.killed_before = killed_unfinished(self.path)  # what earlier recordings killed mid-way left: kept
        self.rec = rr.RecordingStream("pursuit_mj_flight")
        self._tmp = stream_to_unfinished(self.rec, self.path, self._log_static, f"--rerun {self.path}")
        self._closed = False

    def _log_static(self) -> None:
        plan, rec = self.plan, self.rec
        z = plan.height
        border = plan.layout.border()
        rec.log("arena/border", rr.LineStrips3D([[[x0, y0, 0.0], [x1, y1, 0.0]] for x0, y0, x1, y1 in border], colors=(90, 90, 90)), static=True)
        if plan.layout.obstacles:
            rec.log("arena/obstacles", rr.LineStrips3D([_outline(o, z) for o in plan.layout.obstacles], colors=(140, 120, 100)), static=True)
        fence = fence_outline(border, plan.safety.geofence_margin * plan.transform.scale)
        if fence is not None:
            rec.log("arena/fence", rr.LineStrips3D([[[x, y, z] for x, y in fence]], colors=(230, 160, 40)), static=True)
        rec.send_property("flight", rr.AnyValues(name=plan.spec.name, source=plan.spec.source, layout=plan.layout.source, positioning=plan.spec.positioning))

    def log_step(self, t: float, pos: np.ndarray, vel: np.ndarray, command: np.ndarray, vbat: np.ndarray) -> None:
        """One decision step: pos (D, 3) m, vel (D, 3) m/s, command (D, 2) m/s, vbat (D,) V; x, y in the
        layout frame, z the lab height (as the bridge passes them; the same at scale 1)."""
        rec = self.rec
        rec.set_time("flight_time", duration=float(t))
        for i, d in enumerate(self.plan.drones):
            p = pos[i].tolist()
            rec.log(f"drones/{d.name}", rr.Points3D([p], radii=0.06, colors=ROLE_RGB[d.role], labels=d.name))
            rec.log(f"drones/{d.name}/velocity", rr.Arrows3D(origins=[p], vectors=[vel[i].tolist()], colors=(80, 80, 80)))
            rec.log(f"drones/{d.name}/command", rr.Arrows3D(origins=[p], vectors=[[float(command[i, 0]), float(command[i, 1]), 0.0]], colors=ROLE_RGB[d.role]))
            if np.isfinite(vbat[i]):
                rec.log(f"battery/{d.name}", rr.Scalars(float(vbat[i])))
            rec.log(f"height/{d.name}", rr.Scalars(float(pos[i, 2])))

    def log_event(self, record: dict) -> None:
        """One event-log record ({'t', 'kind', ...})."""
        self.rec.set_time("flight_time", duration=float(record["t"]))
        details = ", ".join(f"{k}={v}" for k, v in record.items() if k not in ("t", "time", "kind", "level"))
        self.rec.log("events", rr.TextLog(f"{record['kind']}: {details}" if details else record["kind"], level=LEVEL.get(record.get("level", "info"), "INFO")))

    def close(self) -> None:
        """Finish the file and rename it into place, however the flight ended; CannotWrite if the
        disk took only part of it (what it took is still renamed into place), or if it cannot
        replace the file under its name (it is kept as NAME.new.rrd, io_utils.keep_beside)."""
        if self._closed:
            return
        self._closed = True
        failed = None
        try:
            flush(self.rec, self._tmp)
            self.rec.disconnect()
        except RuntimeError as exc:  # rerun's file writer stopped: a full disk
            failed = exc
        try:
            move_into_place(self._tmp, self.path)
        except OSError as exc:  # a folder or an immutable file under the name: kept as NAME.new.rrd
            raise CannotWrite(f"--rerun {not_replaced_message(self.path, exc, keep_beside(self._tmp, self.path))}") from None
        if failed is not None:
            raise CannotWrite(f"--rerun {self.path}: the disk took only part of the flight (rerun: {failed})")
