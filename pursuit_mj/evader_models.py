"""What flies the evaders: the built-in escape model, or a model of one's own (task key `evader.model`).

`evader.model: janosov` (the default) is pursuit_mj.evader.EscapeModel, tuned by the other
`evader.*` keys. `evader.model: FILE.py:NAME` calls NAME(config, n_worlds, seed) from FILE,
which must give an object with
- `reset(world_ids, seeds)`: new episodes in those worlds (int arrays of one length; the
  seeds are the episodes' own, for randomness that replays by seed);
- `compute(evader_pos, evader_vel, pursuer_pos, pursuer_vel, active, obstacles, dt)`:
  desired velocities (W, M, 2) in m/s, layout frame, from positions and velocities (W, M, 2)
  and (W, N, 2) in m and m/s, `active` (W, M) bool (the free evaders of running worlds),
  `obstacles` (pursuit_mj.geometry.ObstacleSet over the worlds: border and caught evaders'
  capture discs included) and `dt` the decision interval (s). The physics caps the speed at
  `evader_speed`. Every array it gets, and the obstacles', is read-only: they are the env's own
  (the reward terms and captures are measured from them), so writing into one is an error.
Every failure of a model of one's own is a ValueError naming the key and the reference; an
object set as `env.evader_model` is checked alike (`checked_evader_model`), named by its class.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from .config import BUILTIN_EVADER, TaskConfig
from .evader import EscapeModel
from .geometry import ObstacleSet
from .user_file import UserCodeError, checked_real_array, file_sha256, load_named, made_by, what_and_where


def evader_model_sha256(config: TaskConfig) -> str | None:
    """sha256 of the file `config.evader.model` names, None for the built-in model (a resumed eval
    or a render's file name checks that the evaders are the same)."""
    ref = config.evader.model
    return None if ref == BUILTIN_EVADER else file_sha256(ref, "task evader.model")


def make_evader_model(config: TaskConfig, n_worlds: int, seed: int, source: str = "task evader.model"):
    """The model `config.evader.model` names, for `n_worlds` worlds (an EscapeModel, or a
    FileEvaderModel around one's own)."""
    ref = config.evader.model
    if ref == BUILTIN_EVADER:
        return EscapeModel(config, n_worlds, seed)
    factory, path, name = load_named(ref, source)
    where = f"{source} {ref}"
    model = made_by(factory, (config, n_worlds, seed), f"{name}(config, n_worlds, seed)", where, path, ("reset", "compute"),
                    "an evader model: an object with reset(world_ids, seeds) and compute(...) (docs/env_api.md)")
    return FileEvaderModel(model, where, path, (int(n_worlds), config.n_evaders, 2))


def checked_evader_model(model, shape: tuple[int, int, int]):
    """`model` as the env calls it: the built-in model and a file's (already checked) as they are;
    any other object set as `env.evader_model` behind a file model's checks (FileEvaderModel,
    named `env.evader_model CLASS`), for `shape` (W, M, 2). ValueError for an object without
    callable reset and compute."""
    if isinstance(model, (EscapeModel, FileEvaderModel)):
        return model
    missing = [m for m in ("reset", "compute") if not callable(getattr(model, m, None))]
    if missing or isinstance(model, type):
        what = f"the class {model.__name__}, not an instance of it" if isinstance(model, type) else f"{model!r} has no {' or '.join(missing)} method"
        raise ValueError(f"env.evader_model: {what}; it must be an evader model: an object with reset(world_ids, seeds) "
                         f"and compute(...) (docs/env_api.md)")
    return FileEvaderModel(model, f"env.evader_model {type(model).__name__}", None, shape)


def _read_only(array: np.ndarray) -> np.ndarray:
    """A view of `array` that cannot be written through (no copy)."""
    view = np.asarray(array).view()
    view.flags.writeable = False
    return view


class FileEvaderModel:
    """A model of one's own (`model`), its answers checked: `compute` must return real numbers of
    shape (W, M, 2), finite for the active evaders; an exception in it is named by `where` and
    its line in the file (a UserCodeError). It gets read-only views of the env's arrays and
    obstacles: one it writes into is refused, not left to change the rewards and captures."""

    def __init__(self, model, where: str, path: Path | None, shape: tuple[int, int, int]):
        """`path` the model's file (None for an object set on the env: an exception is then placed
        at its deepest line), `shape` (W, M, 2) of what compute must return."""
        self.model = model
        self.where = where
        self._path = path
        self._shape = shape
        self._obstacles: tuple[ObstacleSet, ObstacleSet] | None = None  # (the env's set, its read-only twin)

    def _read_only_obstacles(self, obstacles: ObstacleSet) -> ObstacleSet:
        """`obstacles` with read-only views of its arrays, kept while the env passes the same set
        (so that what the set caches, its ray and distance targets, is computed once)."""
        if self._obstacles is None or self._obstacles[0] is not obstacles:
            frozen = dataclasses.replace(obstacles, **{f.name: _read_only(getattr(obstacles, f.name))
                                                       for f in dataclasses.fields(obstacles)})
            self._obstacles = (obstacles, frozen)
        return self._obstacles[1]

    def reset(self, world_ids: np.ndarray, seeds: np.ndarray | None = None) -> None:
        try:
            self.model.reset(world_ids, seeds)
        except (Exception, SystemExit) as exc:
            raise UserCodeError(f"{self.where}: reset(world_ids, seeds) raised {what_and_where(exc, self._path)}") from exc

    def compute(self, evader_pos: np.ndarray, evader_vel: np.ndarray, pursuer_pos: np.ndarray, pursuer_vel: np.ndarray,
                active: np.ndarray, obstacles: ObstacleSet, dt: float) -> np.ndarray:
        """The model's desired velocities (W, M, 2) m/s world, checked, from the arguments of
        `EscapeModel.compute` (positions m, velocities m/s, world frame; active (W, M) bool; dt s)."""
        arrays = [_read_only(a) for a in (evader_pos, evader_vel, pursuer_pos, pursuer_vel, active)]
        active = arrays[-1]
        try:
            raw = self.model.compute(*arrays, self._read_only_obstacles(obstacles), dt)
        except (Exception, SystemExit) as exc:
            raise UserCodeError(f"{self.where}: compute(...) raised {what_and_where(exc, self._path)}") from exc
        return checked_real_array(raw, self._shape, f"{self.where}: compute", "(worlds, evaders, vx vy in m/s)",
                                  "(world, evader, axis)", counted=active)  # the others' commands are ignored, whatever they are
