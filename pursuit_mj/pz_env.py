"""A PettingZoo `ParallelEnv` over one world of the pursuit task (dicts keyed by agent name).

Agents are the pursuers `pursuer_0 ... pursuer_{N-1}`; evaders are part of the environment.
Observations follow obs_spec.py; actions are desired world-frame velocities in [-1, 1]^2
as a fraction of pursuer_speed. `state()` is the global state for centralised critics.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from .config import TaskConfig, default_config
from .env import PursuitEnv


class PursuitParallelEnv(ParallelEnv):
    metadata = {"name": "pursuit_mj_v0", "render_modes": []}

    def __init__(self, config: TaskConfig | None = None, seed: int = 0, render_mode: str | None = None):
        if render_mode is not None:  # pettingzoo's convention: refuse a mode not in metadata["render_modes"]
            raise ValueError(f"render_mode: {render_mode!r} is not supported, PursuitParallelEnv draws nothing "
                             "(render_mode None); for pictures record `env.batched.snapshot()` (docs/rendering.md)")
        self.config = config or default_config()
        self._env = PursuitEnv(self.config, n_worlds=1, seed=seed, auto_reset=False)
        self.possible_agents = [f"pursuer_{i}" for i in range(self.config.n_pursuers)]
        self.agents: list[str] = []
        self.render_mode = None
        self._started = False
        self._obs_space = spaces.Box(-np.inf, np.inf, (self._env.obs_dim,), np.float32)
        self._act_space = spaces.Box(-1.0, 1.0, (2,), np.float32)
        self.state_space = spaces.Box(-np.inf, np.inf, (self._env.state_dim,), np.float32)

    def observation_space(self, agent: str) -> spaces.Box:
        self._check_agent(agent, "observation_space")
        return self._obs_space

    def action_space(self, agent: str) -> spaces.Box:
        self._check_agent(agent, "action_space")
        return self._act_space

    def _check_agent(self, agent: str, where: str) -> None:
        if agent not in self.possible_agents:
            raise ValueError(f"{where}: no agent {agent!r} (agents: {self.possible_agents})")

    def render(self) -> None:
        """Draws nothing (render_mode None, as gymnasium does without a mode) and says where pictures come from."""
        warnings.warn("PursuitParallelEnv draws nothing itself: record `env.batched.snapshot()` each step "
                      "(pursuit_mj.render, docs/rendering.md) or use `pursuit-mj render`", stacklevel=2)
        return None

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
        self.agents = list(self.possible_agents)
        return self._as_dict(obs[0]), {a: {} for a in self.agents}

    def step(self, actions: dict):
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
        return observations, rewards, terms, truncs, infos

    @staticmethod
    def _action(agent: str, value) -> np.ndarray:
        """One agent's action as float64 (2,), refused as PursuitEnv refuses it (bools, text, complex
        numbers, non-finite values), but naming the agent."""
        raw = np.asarray(value)
        if raw.shape != (2,):
            raise ValueError(f"actions[{agent!r}]: expected shape (2,), got {raw.shape}")
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

    def close(self) -> None:
        pass
