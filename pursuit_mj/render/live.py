"""Frames of a running PursuitEnv for the env APIs' `render()` (PettingZoo, gymnasium vector).

One renderer (one OpenGL context) draws every world, each with its own trails, as `pursuit-mj
render` draws an episode. `check_render_request` refuses a render mode or settings the env
could not honour, naming the argument, when the env is made rather than at its first frame.
"""

from __future__ import annotations

import numpy as np

from ..config import TaskConfig
from ..env import PursuitEnv
from ..layout import Layout
from .episodes import FrameMaker
from .renderer import RenderSettings, check_settings

TRAIL_STEPS = 30  # decision steps of trail behind each drone
KEPT_SCENES = 8  # up to this many worlds, each world's scene (model and GL context, ~20 MB at 640 x 480) stays made


def check_render_request(render_mode, render_settings, config: TaskConfig, layout: Layout) -> None:
    """ValueError naming `render_mode` (None or 'rgb_array') or a field of `render_settings`
    (a RenderSettings, given only with 'rgb_array') that the scenes of `config` and `layout` cannot draw."""
    if render_mode not in (None, "rgb_array"):  # the convention of both APIs: only the modes of metadata
        raise ValueError(f"render_mode: {render_mode!r} is not supported (supported: None, 'rgb_array')")
    if render_settings is None:
        return
    if not isinstance(render_settings, RenderSettings):  # else a deep AttributeError at the first frame
        raise ValueError(f"render_settings: expected a pursuit_mj.render.renderer.RenderSettings (size, camera, "
                         f"quality, key), got {type(render_settings).__name__} {render_settings!r}")
    if render_mode is None:  # it would be ignored: nothing is drawn without a render mode
        raise ValueError("render_settings: given without render_mode='rgb_array', which it needs to draw anything")
    check_settings(render_settings, config, layout, "render_settings.")


class LiveFrames:
    """Captioned frames (H, W, 3) uint8 of the worlds of `env`, trails included.

    Call `push()` after every reset and step, so that the trails follow the drones (a world at the
    first step of an episode starts a new trail, however the episode was started); `draw(w)`
    renders world w now.
    """

    def __init__(self, env: PursuitEnv, settings: RenderSettings | None, title: str):
        self.env = env
        # each world's random obstacles make a scene of its own: kept, a frame of each costs no new GL context.
        # Worlds are drawn in turn, so with more worlds than kept scenes the least recently bound one
        # is always the next needed: then none is kept beyond the bound one
        keep = env.n_worlds if env.n_worlds <= KEPT_SCENES else 1
        self.maker = FrameMaker(env.config, env.world_layouts[0], settings or RenderSettings(), title, TRAIL_STEPS,
                                keep_scenes=keep)
        self.trails = [self.maker.new_trail() for _ in range(env.n_worlds)]
        self._seen = np.full(env.n_worlds, -1)  # env.starts (episodes begun) of each world at the last push

    def push(self) -> None:
        # a new episode, whoever started it (the episode index alone misses reset(seed=...) back to 0)
        started = self.env.starts != self._seen
        self._seen = self.env.starts.copy()
        for w, trail in enumerate(self.trails):  # per world, and only when frames are asked for
            if started[w]:
                trail.clear()
            self.maker.push(self.env.snapshot(w), trail)

    def draw(self, w: int) -> np.ndarray:
        """World w's frame, captioned with its episode's index in the seed's sequence."""
        return self.maker.draw(self.env.snapshot(w), int(self.env.episode[w]), self.trails[w])

    def close(self) -> None:
        self.maker.close()
