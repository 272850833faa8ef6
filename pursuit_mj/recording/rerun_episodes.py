"""Whole pursuit episodes recorded for the rerun viewer (`rerun out.rrd`), many in one file.

Episode k lives under the entity prefix `episode_k/` and is also described by the recording
property `episode_k` (outcome, steps, seed, layout, policy). Inside it:

| entity                          | what (world frame, m, m/s, N)                                  |
|---------------------------------|----------------------------------------------------------------|
| `arena/border`, `arena/boxes`, `arena/cylinders` | the layout's border, boxes/walls, pillars (static) |
| `drones/{name}`                 | pose: translation + attitude quaternion per step               |
| `drones/{name}/body`            | the airframe drawn in the drone frame (static)                 |
| `trails/{name}`                 | the last `trail_length` positions per step                     |
| `perception/{pursuer}`          | pose of the sensing footprint (position, heading)              |
| `perception/{pursuer}/range`    | perception circle or field-of-view wedge (static, local frame; partial observability) |
| `rays/{pursuer}`                | the K range readings as segments from the pursuer, per step    |
| `detections/{pursuer}`          | a segment to each evader it knows: seen (solid colour) or relayed (faded) |
| `capture/{evader}` + `/radius`  | capture radius ring following each evader                      |
| `velocity/{name}/commanded`, `velocity/{name}/actual` | vx, vy scalars                           |
| `thrust/{name}`                 | the four motor thrusts (quadrotor fidelity)                    |
| `reward/{term}`                 | the term per pursuer, each step                                |
| `outcome`                       | a text summary (static) and a log line at the last step        |

Timelines: `step` (decision steps since the episode began) and `sim_time` (s). Episodes are
buffered in memory and sent as columns when they end, which keeps the per-step cost to a
snapshot copy. The file is written as `NAME.unfinished-PID-XXXXXX.rrd`, each episode flushed as it
ends, and renamed on `close` (a recording killed mid-way, kill -9, leaves that file readable).
"""

from __future__ import annotations

import contextlib
import glob
import math
import re
import uuid
from pathlib import Path
from typing import Sequence

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from ..io_utils import CannotWrite, check_writable, keep_beside, killed_unfinished, move_into_place, not_replaced_message
from .unfinished import cannot_write, flush, stream_to_unfinished
from ..layout import Box, Cylinder, Layout, Wall
from ..palette import BORDER_RGBA, OBSTACLE_RGBA, ROLE_RGBA, rgb255
from ..scene import drone_names, wall_heights

APPLICATION_ID = "pursuit_mj"
PURSUER_RGB = rgb255(ROLE_RGBA["pursuer"])
EVADER_RGB = rgb255(ROLE_RGBA["evader"])
SEEN_RGBA = (255, 190, 10, 255)
RELAYED_RGBA = (255, 190, 10, 110)
RAY_RGBA = (120, 120, 120, 90)
OUTCOME_LEVEL = {"success": "INFO", "timeout": "WARN", "collision": "ERROR", "": "INFO"}


def check_rrd_path(path: str | Path, source: str = "--rerun", episodes: bool = False) -> Path:
    """Validate an output .rrd path before any work: ValueError naming `source` if it cannot be
    written; with `episodes` (a RerunEpisodeRecording's), also if a folder holds the name its
    interrupted episodes would be kept under."""
    path = Path(path)
    if path.suffix != ".rrd":
        raise ValueError(f"{source} {path}: expected a file name ending in .rrd")
    partial = interrupted_rrd_path(path)
    if episodes and partial.is_dir():  # found now, not by the rename when the run is interrupted
        raise ValueError(f"{source} {path}: {partial} is a folder; an interrupted run keeps its finished "
                         f"episodes under that name, so it must be free for a file")
    return check_writable(path, source)


def interrupted_rrd_path(path: Path) -> Path:
    """Where an interrupted recording of `path` keeps its finished episodes: out.rrd -> out.interrupted.rrd."""
    return path.with_name(f"{path.stem}.interrupted{path.suffix}")


def _yaw_quat_xyzw(yaw: np.ndarray) -> np.ndarray:
    """Quaternions (..., 4) x, y, z, w (rerun's order) for rotations by yaw (...,) rad about +z."""
    yaw = np.asarray(yaw, float)
    return np.stack([np.zeros_like(yaw), np.zeros_like(yaw), np.sin(yaw / 2), np.cos(yaw / 2)], -1)


def _wxyz_to_xyzw(q: np.ndarray) -> np.ndarray:
    return np.concatenate([q[..., 1:], q[..., :1]], axis=-1)


def _circle(radius: float, start: float = 0.0, stop: float = 2 * math.pi, n: int = 64) -> np.ndarray:
    a = np.linspace(start, stop, n + 1)
    return np.stack([radius * np.cos(a), radius * np.sin(a), np.zeros_like(a)], -1)


def _footprint(radius: float, fov: float) -> np.ndarray:
    """The sensing footprint in the pursuer's heading frame (x forward): a circle or a wedge (P, 3)."""
    if fov >= 2 * math.pi - 1e-9:
        return _circle(radius)
    arc = _circle(radius, -fov / 2, fov / 2, max(8, int(64 * fov / (2 * math.pi))))
    return np.concatenate([np.zeros((1, 3)), arc, np.zeros((1, 3))])


class EpisodeBuffer:
    """Snapshots of one episode (pursuit_mj.env.Snapshot), in step order, until it is sent."""

    def __init__(self, label: dict | None = None):
        self.snapshots: list = []
        self.label = dict(label or {})

    def append(self, snap) -> None:
        self.snapshots.append(snap)

    def __len__(self) -> int:
        return len(self.snapshots)


class RerunEpisodeRecording:
    """An .rrd file that holds any number of episodes (see the module docstring for its layout)."""

    def __init__(self, path: str | Path, trail_length: int = 30, application_id: str = APPLICATION_ID, source: str = "--rerun"):
        self.path = check_rrd_path(path, source, episodes=True)
        self.source = source  # what the user gave the path with (a flag), named in errors
        if isinstance(trail_length, bool) or not isinstance(trail_length, (int, np.integer)) or trail_length < 1:
            raise ValueError(f"trail length: expected an integer >= 1 step, got {trail_length!r}")
        self.trail_length = int(trail_length)
        self.n_episodes = 0
        self.kept: Path | None = None  # where close() left the episodes: path, partial_path or nowhere
        self.lost: str | None = None  # why close() could not write the file (a full disk), if it could not
        self.not_replaced: str | None = None  # why close() kept the file beside its name, if it did
        self.killed_before = killed_unfinished(self.path)  # what earlier recordings killed mid-way left: kept
        self.stream = rr.RecordingStream(application_id, recording_id=uuid.uuid4())
        self._tmp = stream_to_unfinished(self.stream, self.path, lambda: self.stream.log(
            "/", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True), f"{source} {self.path}")
        self._closed = False
        self._thrust = False

    # ------------------------------------------------------------------ episodes

    def add_episode(self, buffer: EpisodeBuffer, record=None) -> str:
        """Send one finished episode; `record` (env.EpisodeRecord) adds seed and outcome details.

        Returns the entity prefix it was written under (e.g. 'episode_3').
        """
        if self._closed:
            raise RuntimeError("add_episode after close")
        if not len(buffer):
            raise ValueError("add_episode: the episode buffer holds no snapshots")
        prefix = f"episode_{self.n_episodes}"
        snaps = buffer.snapshots
        first, last = snaps[0], snaps[-1]
        cfg = first.config
        names = drone_names(cfg.n_pursuers, cfg.n_evaders)
        N = cfg.n_pursuers
        steps = np.array([s.step for s in snaps], np.int64)
        times = np.array([s.time for s in snaps])
        index = [rr.TimeColumn("step", sequence=steps), rr.TimeColumn("sim_time", duration=times)]
        pos = np.stack([np.concatenate([s.pursuer_pos, s.evader_pos]) for s in snaps])  # (T, D, 3)
        quat = np.stack([np.concatenate([s.pursuer_quat, s.evader_quat]) for s in snaps])  # (T, D, 4) wxyz
        vel = np.stack([np.concatenate([s.pursuer_vel, s.evader_vel]) for s in snaps])  # (T, D, 3)
        send = self.stream.send_columns
        self._log_arena(prefix, first.layout, first.config.flight_height)
        for d, name in enumerate(names):
            rgb = PURSUER_RGB if d < N else EVADER_RGB
            self._log_body(f"{prefix}/drones/{name}/body", rgb)
            send(f"{prefix}/drones/{name}", index, rr.Transform3D.columns(translation=pos[:, d], quaternion=_wxyz_to_xyzw(quat[:, d])))
            self._send_trail(f"{prefix}/trails/{name}", index, pos[:, d], rgb)
        self._send_perception(prefix, index, snaps, names[:N], pos[:, :N])
        for j, name in enumerate(names[N:]):
            self.stream.log(f"{prefix}/capture/{name}/radius", rr.LineStrips3D([_circle(cfg.capture_radius)], colors=[EVADER_RGB]), static=True)
            send(f"{prefix}/capture/{name}", index, rr.Transform3D.columns(translation=pos[:, N + j]))
        self._send_motion(prefix, index, snaps, names, vel, cfg.fidelity)
        self._thrust |= cfg.fidelity == "quadrotor"
        self._send_rewards(prefix, index, snaps, names[:N])
        self._log_outcome(prefix, buffer.label, last, record)
        try:
            flush(self.stream, self._tmp)  # on disk as each episode ends: a recording killed later (kill -9) keeps it
        except RuntimeError as exc:  # rerun's file writer stopped (a full disk) or stalled
            self.lost = str(exc)
            raise CannotWrite(cannot_write(f"{self.source} {self.path}", exc)) from None
        self.n_episodes += 1
        return prefix

    def _log_arena(self, prefix: str, layout: Layout, flight_height: float) -> None:
        log = self.stream.log
        height = wall_heights(flight_height)[0]
        seg = layout.border()
        z = 0.02
        strips = [[[x0, y0, z], [x1, y1, z]] for x0, y0, x1, y1 in seg]
        log(f"{prefix}/arena/border", rr.LineStrips3D(strips, colors=[rgb255(BORDER_RGBA)]), static=True)
        first_random = len(layout.obstacles) - layout.n_random
        colour = [rgb255(OBSTACLE_RGBA["random" if k >= first_random else "fixed"]) for k in range(len(layout.obstacles))]
        boxes = [o.as_box() if isinstance(o, Wall) else o for o in layout.obstacles if isinstance(o, (Box, Wall))]
        box_colours = [c for o, c in zip(layout.obstacles, colour) if isinstance(o, (Box, Wall))]
        if boxes:
            log(f"{prefix}/arena/boxes", rr.Boxes3D(
                half_sizes=[[b.size[0] / 2, b.size[1] / 2, height / 2] for b in boxes],
                centers=[[b.center[0], b.center[1], height / 2] for b in boxes],
                quaternions=_yaw_quat_xyzw([b.yaw for b in boxes]),
                colors=box_colours, fill_mode="solid"), static=True)
        cyls = [o for o in layout.obstacles if isinstance(o, Cylinder)]
        cyl_colours = [c for o, c in zip(layout.obstacles, colour) if isinstance(o, Cylinder)]
        if cyls:
            log(f"{prefix}/arena/cylinders", rr.Cylinders3D(
                lengths=[height] * len(cyls), radii=[c.radius for c in cyls],
                centers=[[c.center[0], c.center[1], height / 2] for c in cyls],
                colors=cyl_colours, fill_mode="solid"), static=True)
        log(f"{prefix}/arena/info", rr.TextDocument(f"layout **{layout.name}** ({layout.source}), "
                                                  f"{layout.width} x {layout.height} m, {len(layout.obstacles)} obstacles "
                                                  f"({layout.n_random} of them placed at random, in orange)",
                                                  media_type="text/markdown"), static=True)

    def _log_body(self, entity: str, rgb) -> None:
        """A Crazyflie-sized X frame (two 92 mm arms) in the drone frame."""
        q = _yaw_quat_xyzw(np.array([math.pi / 4, -math.pi / 4]))
        self.stream.log(entity, rr.Boxes3D(half_sizes=[[0.046, 0.004, 0.003]] * 2, quaternions=q, colors=[rgb], fill_mode="solid"), static=True)

    def _send_trail(self, entity: str, index, pos: np.ndarray, rgb) -> None:
        """pos (T, 3): row t holds the strip of positions t-L+1 .. t."""
        L = self.trail_length
        strips = [pos[max(0, t - L + 1): t + 1] for t in range(len(pos))]
        self.stream.send_columns(entity, index, rr.LineStrips3D.columns(strips=strips, colors=[rgb] * len(strips)))

    def _send_perception(self, prefix: str, index, snaps: Sequence, pursuers: list[str], pos: np.ndarray) -> None:
        cfg = snaps[0].config
        T, N = pos.shape[:2]
        heading = np.stack([s.heading for s in snaps])  # (T, N) rad
        seen = np.stack([s.seen for s in snaps])  # (T, N, M)
        known = np.stack([s.known for s in snaps])
        captured = np.stack([s.captured for s in snaps])  # (T, M)
        evader = np.stack([s.evader_pos for s in snaps])  # (T, M, 3)
        rays = np.stack([s.rays for s in snaps])  # (T, N, K) m
        K = rays.shape[-1]
        ray_dirs = np.stack([np.cos(2 * np.pi * np.arange(K) / max(K, 1)), np.sin(2 * np.pi * np.arange(K) / max(K, 1)), np.zeros(K)], -1)
        footprint = _footprint(cfg.perception_radius, cfg.field_of_view)
        send = self.stream.send_columns
        for i, name in enumerate(pursuers):
            base = f"{prefix}/perception/{name}"
            if cfg.observability == "partial":  # in full observability nothing limits what a pursuer knows
                self.stream.log(f"{base}/range", rr.LineStrips3D([footprint], colors=[PURSUER_RGB + (160,)]), static=True)
            send(base, index, rr.Transform3D.columns(translation=pos[:, i], quaternion=_yaw_quat_xyzw(heading[:, i])))
            # detections: one segment per known evader per step, coloured by direct / relayed
            mask = known[:, i] & ~captured
            t_idx, j_idx = np.nonzero(mask)
            strips = np.stack([pos[t_idx, i], evader[t_idx, j_idx]], axis=1)  # (S, 2, 3)
            colors = np.where(seen[t_idx, i, j_idx][:, None], SEEN_RGBA, RELAYED_RGBA).astype(np.uint8)
            cols = rr.LineStrips3D.columns(strips=strips, colors=colors).partition(mask.sum(1))
            send(f"{prefix}/detections/{name}", index, cols)
            if K:
                # ray segments in the world frame, from the pursuer outwards, K per step
                ends = pos[:, i, None, :] + rays[:, i, :, None] * ray_dirs[None]  # (T, K, 3)
                seg = np.stack([np.broadcast_to(pos[:, i, None, :], ends.shape), ends], axis=2).reshape(T * K, 2, 3)
                send(f"{prefix}/rays/{name}", index, rr.LineStrips3D.columns(strips=seg, colors=np.tile(RAY_RGBA, (T * K, 1)).astype(np.uint8)).partition(np.full(T, K)))

    def _send_motion(self, prefix: str, index, snaps: Sequence, names: list[str], vel: np.ndarray, fidelity: str) -> None:
        cmd = np.stack([s.commands for s in snaps])  # (T, D, 2) m/s
        thrust = np.stack([s.thrust for s in snaps])  # (T, D, 4) N
        send, log = self.stream.send_columns, self.stream.log
        for d, name in enumerate(names):
            for kind, values in (("commanded", cmd[:, d]), ("actual", vel[:, d, :2])):
                entity = f"{prefix}/velocity/{name}/{kind}"
                log(entity, rr.SeriesLines(names=[f"{kind} vx", f"{kind} vy"]), static=True)
                send(entity, index, rr.Scalars.columns(scalars=values))
            if fidelity == "quadrotor":
                log(f"{prefix}/thrust/{name}", rr.SeriesLines(names=[f"motor_{m}" for m in range(4)]), static=True)
                send(f"{prefix}/thrust/{name}", index, rr.Scalars.columns(scalars=thrust[:, d]))

    def _send_rewards(self, prefix: str, index, snaps: Sequence, pursuers: list[str]) -> None:
        for term in snaps[0].reward_terms:
            values = np.stack([s.reward_terms[term] for s in snaps]).astype(np.float64)  # (T, N)
            entity = f"{prefix}/reward/{term}"
            self.stream.log(entity, rr.SeriesLines(names=pursuers), static=True)
            self.stream.send_columns(entity, index, rr.Scalars.columns(scalars=values))

    def _log_outcome(self, prefix: str, label: dict, last, record) -> None:
        info = dict(label)
        info.update(outcome=last.outcome or "running", steps=int(last.step), layout=last.layout.name,
                    fidelity=last.config.fidelity, captured=int(np.sum(last.captured)))
        if record is not None:
            info.update(seed=int(record.seed), world=int(record.world), episode=int(record.episode))
            if record.time_to_capture is not None:
                info["time_to_capture_s"] = float(record.time_to_capture)
            for k, v in record.returns.items():
                info[f"return_{k}"] = float(v)
        text = "\n".join(f"- **{k}**: {v}" for k, v in info.items())
        self.stream.log(f"{prefix}/outcome", rr.TextDocument(f"### {prefix}\n{text}", media_type="text/markdown"), static=True)
        self.stream.set_time("step", sequence=int(last.step))
        self.stream.set_time("sim_time", duration=float(last.time))
        self.stream.log(f"{prefix}/outcome", rr.TextLog(f"{info['outcome']} after {info['steps']} steps", level=OUTCOME_LEVEL.get(last.outcome, "INFO")))
        self.stream.reset_time()
        self.stream.send_property(prefix, rr.AnyValues(**info))

    # ------------------------------------------------------------------ file

    def blueprint(self) -> rrb.Blueprint:
        """The viewer layout: one tab per episode with its 3D scene, reward / velocity / thrust plots and outcome."""
        tabs = []
        for k in range(self.n_episodes):
            p = f"/episode_{k}"
            plots = [rrb.TimeSeriesView(origin=f"{p}/reward", name="reward terms"),
                     rrb.TimeSeriesView(origin=f"{p}/velocity", name="velocity: commanded vs actual (m/s)")]
            if self._thrust:
                plots.append(rrb.TimeSeriesView(origin=f"{p}/thrust", name="motor thrust (N)"))
            plots.append(rrb.TextDocumentView(origin=f"{p}/outcome", name="outcome"))
            tabs.append(rrb.Horizontal(rrb.Spatial3DView(origin=p, name=f"episode {k}"), rrb.Vertical(*plots), column_shares=[3, 2], name=f"episode {k}"))
        return rrb.Blueprint(rrb.Tabs(*tabs) if tabs else rrb.Spatial3DView(origin="/"), collapse_panels=False)

    @property
    def partial_path(self) -> Path:
        """Where an interrupted recording keeps its finished episodes: out.rrd -> out.interrupted.rrd."""
        return interrupted_rrd_path(self.path)

    def _interrupted_files(self) -> dict[int, Path]:
        """{number: file} of the interrupted runs' episodes kept beside `path`: out.interrupted.rrd
        is 1, out.interrupted-K.rrd is K."""
        pattern = re.compile(re.escape(f"{self.path.stem}.interrupted") + r"(?:-([2-9]|[1-9]\d+))?" + re.escape(self.path.suffix))
        found = {}
        for entry in self.path.parent.glob(f"{glob.escape(self.path.stem)}.interrupted*{self.path.suffix}"):
            match = pattern.fullmatch(entry.name)
            if match and not entry.is_dir():
                found[int(match.group(1) or 1)] = entry
        return dict(sorted(found.items()))

    def _free_partial_path(self) -> Path:
        """partial_path, or out.interrupted-K.rrd numbered after the last one there when earlier
        interrupted runs' episodes are kept: they are not replaced, and the numbers follow the runs."""
        kept = self._interrupted_files()
        if not kept and not self.partial_path.exists():
            return self.partial_path
        return self.path.with_name(f"{self.path.stem}.interrupted-{max(kept, default=1) + 1}{self.path.suffix}")

    def _earlier_interrupted(self) -> str:
        """'; A, B beside it keep earlier interrupted runs' episodes' (or '' when there are none)."""
        earlier = [str(p) for p in self._interrupted_files().values() if p != self.kept]
        if not earlier:
            return ""
        what = "keeps an earlier interrupted run's" if len(earlier) == 1 else "keep earlier interrupted runs'"
        return f"; {', '.join(earlier)} beside it {what} episodes"

    def summary(self) -> str:
        """One line for the user about where the episodes went, once closed."""
        n = f"{self.n_episodes} episode{'' if self.n_episodes == 1 else 's'}"
        killed = "".join(f"; {p} beside it holds what a recording killed before it finished had written"
                         for p in self.killed_before if p.is_file())
        if self.not_replaced is not None and self.kept is not None:
            return f"{self.source} {self.not_replaced} ({n}; open with: rerun {self.kept}){self._earlier_interrupted()}{killed}"
        if self.kept == self.path:
            return f"wrote {self.path} ({n}; open with: rerun {self.path}){self._earlier_interrupted()}{killed}"
        if self.kept is not None:
            return (f"interrupted: the {n} finished before it {'is' if self.n_episodes == 1 else 'are'} in {self.kept} (open with: rerun {self.kept}); "
                    f"{self.path} was not written{self._earlier_interrupted()}{killed}")
        if self.lost is not None and self.n_episodes:
            return f"the {n} recorded could not be written ({self.lost}): neither {self.path} nor {self.partial_path} holds them"
        if self.lost is not None:  # the first episode's write failed (a full disk): nothing was interrupted
            return f"no episode was recorded: {self.path} could not be written ({self.lost})"
        return f"interrupted before any episode finished: {self.path} was not written"

    def close(self, ok: bool = True) -> Path | None:
        """Finish the file; returns where its episodes are (also `kept`), None if nowhere.

        ok: flush and rename it onto `path` (CannotWrite naming the flag, `source`, and the file
        if it could not be written, a full disk: nothing is left then). Not ok (an error, Ctrl-C,
        SIGTERM): the finished episodes are kept under `partial_path` with the recording property
        `interrupted`, so that `path` only ever holds a whole run (and an earlier one there
        survives); when earlier interrupted runs' episodes are there, under out.interrupted-K.rrd
        numbered after the last of them; a recording without a finished episode is discarded.
        Either way, a finished file that cannot replace the file under its name (a folder or an
        immutable file there) is kept beside it as out.new.rrd (io_utils.keep_beside) and
        `summary` says where; with ok, CannotWrite naming the flag and that file as well.
        """
        if self._closed:
            return self.kept
        self._closed = True
        if self.lost is not None:  # an episode could not be written (add_episode said so): nothing is kept
            self._tmp.unlink(missing_ok=True)  # (the stream is not disconnected: unfinished.FLUSH_TIMEOUT_S)
            return None
        keep = ok or self.n_episodes > 0
        if keep:
            if not ok:
                self.stream.send_property("interrupted", rr.AnyValues(finished_episodes=self.n_episodes))
            self.stream.send_blueprint(self.blueprint())
        try:
            flush(self.stream, self._tmp)
            self.stream.disconnect()
        except RuntimeError as exc:  # rerun's file writer stopped: a full disk
            return self._lost(ok, exc)
        if not keep:  # interrupted before any episode finished
            self._tmp.unlink(missing_ok=True)
            return None
        target = self.path if ok else self._free_partial_path()
        try:
            self.kept = move_into_place(self._tmp, target)
        except OSError as exc:  # a folder or an immutable file under the name, a removed folder
            return self._not_replaced(ok, target, exc)
        return self.kept

    def _not_replaced(self, ok: bool, target: Path, exc: OSError) -> Path | None:
        """The finished file could not be renamed onto `target`: keep it beside it (out.new.rrd)
        rather than delete the episodes; CannotWrite naming the flag and where they are if the run
        had ended well (an interrupted one stays interrupted; `summary` says where they are)."""
        self.kept = keep_beside(self._tmp, target)
        self.not_replaced = not_replaced_message(target, exc, self.kept)
        if self.kept is None:
            self.lost = str(exc)
        if ok:
            raise CannotWrite(f"{self.source} {self.not_replaced}")
        return self.kept

    def _lost(self, ok: bool, exc: Exception) -> None:
        """The file could not be written: remove it; CannotWrite naming it if the run had ended well
        (an interrupted one stays interrupted; `summary` says its episodes are lost)."""
        self.lost = str(exc)
        self._tmp.unlink(missing_ok=True)
        if ok:
            raise CannotWrite(cannot_write(f"{self.source} {self.path}", exc)) from None
        return None

    def __enter__(self) -> "RerunEpisodeRecording":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close(ok=exc_type is None)
