"""A PettingZoo `ParallelEnv` over one world of the pursuit task (dicts keyed by agent name).

Agents are the pursuers `pursuer_0 ... pursuer_{N-1}`; evaders are part of the environment.
Observations follow obs_spec.py; actions are desired world-frame velocities in [-1, 1]^2
as a fraction of pursuer_speed. `state()` is the global state for centralised critics.
With `render_mode="rgb_array"`, `render()` returns the frame `pursuit-mj render` would draw.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from .config import TaskConfig, checked_task_config, default_config
from .env import MaskedValues, PursuitEnv, check_seed, plain_array


class PursuitParallelEnv(ParallelEnv):
    metadata = {"name": "pursuit_mj_v0", "render_modes": ["rgb_array"]}

    def __init__(self, config: TaskConfig | None = None, seed: int = 0, render_mode: str | None = None,
                 render_settings=None, extra_rewards=None):
        """render_mode None (render() draws nothing) or 'rgb_array' (render() returns the current
        frame (H, W, 3) uint8, top view with trails, caption and colour key); render_settings a
        pursuit_mj.render.renderer.RenderSettings (size, camera, quality; default 640 x 480 top view);
        extra_rewards {name: term} reward terms of one's own (as PursuitEnv's; each term sees one world)."""
        if render_mode not in (None, "rgb_array"):  # before the config: the first mistake a user meets
            raise ValueError(f"render_mode: {render_mode!r} is not supported (supported: None, 'rgb_array')")
        # an empty dict is not "no config": it and every other non-TaskConfig are refused by name
        self.config = default_config() if config is None else checked_task_config(config, "PursuitParallelEnv config")
        self.metadata = {**self.metadata, "render_fps": 1.0 / self.config.control_dt}  # one frame per decision step
        self._env = PursuitEnv(self.config, n_worlds=1, seed=check_seed(seed, "PursuitParallelEnv seed"), auto_reset=False,
                               extra_rewards=extra_rewards)
        if render_mode is not None or render_settings is not None:  # now, naming its fields, not at the first reset
            from .render.live import check_render_request

            check_render_request(render_mode, render_settings, self.config, self._env.world_layouts[0])
        self.possible_agents = [f"pursuer_{i}" for i in range(self.config.n_pursuers)]
        self.agents: list[str] = []
        self.render_mode = render_mode
        self._render_settings = render_settings
        self._frames = None  # the LiveFrames of rgb_array mode, made at the first reset
        self._closed = False  # close() freed the renderer; a reset makes a new one
        self._started = False
        self._obs_space = spaces.Box(-np.inf, np.inf, (self._env.obs_dim,), np.float32)
        self._act_space = spaces.Box(-1.0, 1.0, (2,), np.float32)
        self.state_space = spaces.Box(-np.inf, np.inf, (self._env.state_dim,), np.float32)
        self.observation_spaces = {a: self._obs_space for a in self.possible_agents}  # as ParallelEnv declares them
        self.action_spaces = {a: self._act_space for a in self.possible_agents}

    def observation_space(self, agent: str) -> spaces.Box:
        self._check_agent(agent, "observation_space")
        return self._obs_space

    def action_space(self, agent: str) -> spaces.Box:
        self._check_agent(agent, "action_space")
        return self._act_space

    def _check_agent(self, agent: str, where: str) -> None:
        if agent not in self.possible_agents:
            raise ValueError(f"{where}: no agent {agent!r} (agents: {self.possible_agents})")

    def render(self) -> np.ndarray | None:
        """The current frame (H, W, 3) uint8 in rgb_array mode; without a mode nothing is drawn
        (as gymnasium does), with a warning that says how to get pictures."""
        if self.render_mode is None:
            warnings.warn("PursuitParallelEnv was made without render_mode and draws nothing: pass "
                          "render_mode='rgb_array', or use `pursuit-mj render`", stacklevel=2)
            return None
        if self._frames is None:
            if self._closed:
                raise RuntimeError("render() called after close(): call reset() to draw again")
            raise RuntimeError("render() called before reset(): call reset() first")
        return self._frames.draw(0)

    @property
    def obs_spec(self):
        return self._env.obs_spec

    @property
    def batched(self) -> PursuitEnv:
        """The underlying one-world batched environment (read only, for recorders)."""
        return self._env

    def reset(self, seed: int | None = None, options: dict | None = None):
        """A new episode: with `seed`, episode 0 of that seed's sequence, else the next episode of the
        current one (never a replay). `options` is accepted for the API and ignored (pettingzoo's
        own API test passes some); the task is set by the config."""
        obs = self._env.reset(seed=seed)
        self._started = True
        self._closed = False
        self.agents = list(self.possible_agents)
        if self.render_mode == "rgb_array":
            self._start_frames()
        return self._as_dict(obs[0]), {a: {} for a in self.agents}

    def step(self, actions: dict):
        if self._env.closed:  # close() freed the simulation (a reset builds it anew)
            raise ValueError("step() called after close(): call reset() first")
        if not self.agents:
            if not self._started:
                raise ValueError("step() called before reset(): call reset() first")
            raise ValueError("step() called on a finished episode: call reset() first")
        if not isinstance(actions, Mapping):
            raise ValueError(f"actions: expected a dict {{agent: (vx, vy)}} for agents {self.agents}, got {type(actions).__name__}")
        missing = [a for a in self.agents if a not in actions]
        unknown = [a for a in actions if a not in self.agents]
        if missing or unknown:
            raise ValueError(f"actions: missing agents {missing}, unknown agents {unknown} (expected {self.agents})")
        arr = np.stack([self._action(a, actions[a]) for a in self.agents])
        obs, reward, term, trunc, info = self._env.step(arr[None])
        agents = self.agents
        observations = self._as_dict(obs[0])
        rewards = {a: float(reward[0, i]) for i, a in enumerate(agents)}
        terms = {a: bool(term[0]) for a in agents}
        truncs = {a: bool(trunc[0]) for a in agents}
        infos = {
            a: {"reward_terms": {k: float(v[0, i]) for k, v in info["reward_terms"].items()}, "outcome": str(info["outcome"][0])}
            for i, a in enumerate(agents)
        }
        if term[0] or trunc[0]:
            self.agents = []
        if self._frames is not None:
            self._frames.push()
        return observations, rewards, terms, truncs, infos

    @staticmethod
    def _action(agent: str, value) -> np.ndarray:
        """One agent's action as float64 (2,), refused as PursuitEnv refuses it (bools, text, complex
        numbers, non-finite values), but naming the agent."""
        try:
            raw = plain_array(value, f"actions[{agent!r}]")
        except MaskedValues:
            raise
        except ValueError:  # nested lists of unequal lengths
            raise ValueError(f"actions[{agent!r}]: expected shape (2,), got a ragged list") from None
        if raw.shape != (2,):  # the value as given: None or 0.5 have numpy's shape (), which says little
            got = _shown(value) if raw.ndim == 0 else f"shape {raw.shape}: {_shown(value)}"
            raise ValueError(f"actions[{agent!r}]: expected shape (2,) (vx, vy), got {got}")
        if raw.dtype.kind not in "fiu":  # no silent cast: True would be full speed, 1+2j would lose its 2j
            raise ValueError(f"actions[{agent!r}]: expected real numbers (vx, vy), got an array of dtype {raw.dtype}")
        a = raw.astype(np.float64)
        if not np.isfinite(a).all():
            raise ValueError(f"actions[{agent!r}]: non-finite value in {a.tolist()}")
        return a

    def state(self) -> np.ndarray:
        """The global state (state_dim,) float32 of the one world (PursuitEnv.global_state)."""
        if not self._started:
            raise RuntimeError("state() called before reset(): call reset() first")
        return self._env.global_state()[0]

    def _as_dict(self, obs: np.ndarray) -> dict[str, np.ndarray]:
        return {a: obs[i] for i, a in enumerate(self.possible_agents)}

    def _start_frames(self) -> None:
        """Make the renderer (once: an OpenGL context) and start this episode's trails."""
        if self._frames is None:
            from .render.live import LiveFrames

            self._frames = LiveFrames(self._env, self._render_settings, "pursuit_mj_v0")
        self._frames.push()

    def close(self) -> None:
        """Free the renderer, if one was made, and the simulation (PursuitEnv.close); harmless to call
        again. reset() starts again: a new simulation, as if never closed."""
        if self._frames is not None:
            self._frames.close()
            self._frames = None
            self._closed = True
        self._env.close()


def _shown(value, limit: int = 80) -> str:
    """`value`'s repr on one line, cut to `limit` characters (with '...') for an error message."""
    text = " ".join(repr(value).split())
    return text if len(text) <= limit else text[:limit - 3] + "..."
