"""The batched pursuit env as a gymnasium `VectorEnv`: one sub-environment per pursuer of each world.

For trainers written against gymnasium's vector API (CleanRL-style PPO loops, gymnasium's
vector wrappers, libraries that take a `gymnasium.vector.VectorEnv`) that learn one policy
shared by every pursuer: independent learners with parameter sharing, as `pursuit-mj train`
trains. Slot i is pursuer i % N of world i // N, so `num_envs` is n_worlds x n_pursuers, and
every array is PursuitEnv's (W, N, ...) array with its first two axes flattened.

A world's episode ends for all its pursuers at once: their slots terminate (capture or
collision) or truncate (timeout) together. How they restart is gymnasium's autoreset mode:
- `AutoresetMode.NEXT_STEP` (the default, gymnasium's own, which its observation wrappers
  need): the step that ends an episode returns its last observation; the next step starts the
  new episode in those slots, ignoring their actions (still checked: a NaN there is refused as
  anywhere), with reward 0 and neither flag set.
- `AutoresetMode.SAME_STEP` (no idle step, as `pursuit-mj train` collects): the step that ends
  an episode returns the new episode's first observation, info["final_obs"][i] the ended
  episode's last observation of slot i (None where slot i did not end; info["_final_obs"]
  marks the ended slots), info["final_state"] (num_envs, state_dim) float32 each slot's world's last
  global state (PursuitEnv.global_state, for a centralised critic's bootstrap; 0 in slots that did
  not end, as its mask says), and info["final_info"] that step's reward terms and outcome.
In both modes the ending step's info["episode_record"][i] is the ended world's EpisodeRecord
(info["_episode_record"] marks the slots that have one): outcome, steps, time_to_capture, returns.
Either way a world runs the same episodes, by its seed sequence (docs/env_api.md). The evaders
are part of the environment; `batched` is the underlying PursuitEnv (global state, snapshots).
With render_mode "rgb_array", `render()` returns one frame per slot, as `pursuit-mj render`
draws it (the slots of a world share their world's frame).

Importing this module registers ENV_ID with gymnasium, so that
`gymnasium.make_vec("pursuit_mj.vector_env:pursuit_mj/Pursuit-v0", num_envs=24, config=...)`
makes the env of num_envs / n_pursuers worlds (`make_vector_env`).
"""

from __future__ import annotations

import warnings
from typing import Any, Mapping

import gymnasium
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from .config import TaskConfig, default_config, task_config_from
from .env import MaskedValues, PursuitEnv, check_seed, plain_array

MODES = (AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP)
ENV_ID = "pursuit_mj/Pursuit-v0"  # gymnasium's id of the vector env (make_vec only: it has no single-env form)


class PursuitVectorEnv(VectorEnv):
    """n_worlds worlds of the pursuit task as n_worlds x n_pursuers gymnasium sub-environments.

    n_worlds, seed, layouts, nthread and extra_rewards are PursuitEnv's (docs/env_api.md); config
    too, or task keys as a mapping, or a task file or preset name (config.task_config_from).
    autoreset_mode an AutoresetMode (or its value, "NextStep" / "SameStep"; module docstring).
    render_mode None (render() draws nothing) or "rgb_array"; render_settings a
    pursuit_mj.render.renderer.RenderSettings (default 640 x 480 top view), as PursuitParallelEnv's.
    single_observation_space: Box(-inf, inf, (obs_dim,), float32), PursuitEnv's observation of
    one pursuer (layout in obs_spec.py, `obs_spec`). single_action_space: Box(-1, 1, (2,),
    float32), the desired world-frame velocity as a fraction of pursuer_speed (clipped to the
    Box, and its norm to 1, as PursuitEnv clips it).
    """

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": ["rgb_array"]}

    def __init__(self, config: TaskConfig | Mapping | str | None = None, n_worlds: int = 1, seed: int = 0, layouts=None,
                 nthread: int = 0, extra_rewards=None, autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
                 render_mode: str | None = None, render_settings=None):
        mode = _checked_mode(autoreset_mode)
        config = default_config() if config is None else task_config_from(config, "PursuitVectorEnv config")
        self.batched = PursuitEnv(config, n_worlds=n_worlds, seed=check_seed(seed, "PursuitVectorEnv seed"),
                                  auto_reset=mode == AutoresetMode.SAME_STEP, layouts=layouts, nthread=nthread,
                                  extra_rewards=extra_rewards)
        for name in self.batched.extra_rewards:  # gymnasium's infos keep "_KEY" for the mask of KEY
            if name.startswith("_"):
                raise ValueError(f"PursuitVectorEnv extra_rewards: {name!r} starts with '_', which gymnasium's vector infos "
                                 f"keep for masks ('_capture' marks the slots that have 'capture'); give it another name")
        self.config = config
        self.autoreset_mode = mode
        self.n_worlds, self.n_pursuers = self.batched.n_worlds, self.batched.n_pursuers
        self.num_envs = self.n_worlds * self.n_pursuers
        self.metadata = {**self.metadata, "autoreset_mode": mode, "render_fps": 1.0 / config.control_dt}
        if render_mode is not None or render_settings is not None:  # now, not at the first frame
            from .render.live import check_render_request

            check_render_request(render_mode, render_settings, config, self.batched.world_layouts[0])
        self.render_mode = render_mode
        self._render_settings = render_settings
        self._frames = None  # the LiveFrames of rgb_array mode, made at the first reset
        self.single_observation_space = spaces.Box(-np.inf, np.inf, (self.batched.obs_dim,), np.float32)
        self.single_action_space = spaces.Box(-1.0, 1.0, (2,), np.float32)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)

    @property
    def obs_spec(self):
        """The observation index map (pursuit_mj.obs_spec.ObsSpec) of every slot."""
        return self.batched.obs_spec

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        """New episodes in every world: obs (num_envs, obs_dim) float32 and an empty info.

        With an int `seed`, episode 0 of that seed's sequence in every world (PursuitEnv.reset),
        else the next episode of each (never a replay). Per-slot seeds are refused: the pursuers of
        a world share one episode (give per-world episode seeds with `batched.reset(seeds=...)`).
        """
        if seed is not None and (isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer))):
            raise ValueError(f"reset seed: expected an int or None, got {seed!r} (the {self.n_pursuers} pursuers of a "
                             f"world share one episode: give per-world episode seeds with env.batched.reset(seeds=...))")
        if options:
            raise ValueError(f"reset options: PursuitVectorEnv takes none (its config sets the task), got {options!r}")
        obs = self.batched.reset(seed=seed)
        self.closed = False  # a reset after close() makes a renderer that the next close() frees
        self._push_frames()
        if seed is not None:
            self._np_random, self._np_random_seed = np.random.default_rng(seed), int(seed)
        return self._flat(obs), {}

    def step(self, actions) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """One decision step of every world. actions (num_envs, 2). Returns obs (num_envs, obs_dim)
        float32, rewards (num_envs,) float64, terminations and truncations (num_envs,) bool, and infos:
        "reward_terms" {term: (num_envs,) float32} and "outcome" (num_envs,) str ("" unless the slot's
        episode ended in this step), each key with its "_key" mask, "episode_record" (the world's
        EpisodeRecord) for the slots whose episode ended, and in SAME_STEP mode also "final_obs",
        "final_state" and "final_info" for them (module docstring)."""
        if self.batched.closed:  # close() freed the simulation (a reset builds it anew)
            raise RuntimeError("step() called after close(): call reset() first")
        if not self.batched.started:  # neither reset() nor batched.reset() yet
            raise RuntimeError("step() called before reset(): call reset() first")
        a = self._checked_actions(actions)
        W, N = self.n_worlds, self.n_pursuers
        # NEXT_STEP: the worlds whose episode ended in the last step (the batched env's, whoever stepped
        # or reset it) are frozen in this one (no physics, no reward) and restart after it
        waiting = self.batched.done.copy()
        obs, reward, terminated, truncated, info = self.batched.step(a.reshape(W, N, 2))
        ended_worlds = terminated | truncated
        if waiting.any():
            obs = self.batched.reset_worlds(np.flatnonzero(waiting))
        self._push_frames()
        every = np.ones(self.num_envs, bool)
        terms = {k: v.reshape(-1) for k, v in info["reward_terms"].items()}
        outcome = np.repeat(info["outcome"], N)
        infos: dict[str, Any] = {"reward_terms": _with_masks(terms, every), "_reward_terms": every.copy(),
                                 "outcome": outcome, "_outcome": every.copy()}
        ended = np.repeat(ended_worlds, N)
        if ended.any():  # the ended worlds' EpisodeRecords, in each of their slots (PursuitEnv keeps none)
            records = np.full(self.num_envs, None, dtype=object)
            for record in info["episodes"]:
                for i in range(record.world * N, (record.world + 1) * N):
                    records[i] = record
            infos["episode_record"], infos["_episode_record"] = records, ended.copy()
        if self.autoreset_mode == AutoresetMode.SAME_STEP and ended.any():
            final_obs = np.full(self.num_envs, None, dtype=object)
            last = info["final_obs"].reshape(self.num_envs, -1)
            for i in np.flatnonzero(ended):  # at episode ends only
                final_obs[i] = last[i]
            final_terms = {k: np.where(ended, v, np.float32(0.0)) for k, v in terms.items()}
            infos["final_obs"], infos["_final_obs"] = final_obs, ended.copy()
            # the world restarted, so global_state() is the new episode's: the last one, per slot (0 where not ended)
            final_state = np.where(ended[:, None], np.repeat(info["final_state"], N, axis=0), np.float32(0.0))
            infos["final_state"], infos["_final_state"] = final_state, ended.copy()
            infos["final_info"] = {"reward_terms": _with_masks(final_terms, ended), "_reward_terms": ended.copy(),
                                   "outcome": outcome.copy(), "_outcome": ended.copy()}
            infos["_final_info"] = ended.copy()
        return (self._flat(obs), reward.reshape(-1).astype(np.float64), np.repeat(terminated, N),
                np.repeat(truncated, N), infos)

    def render(self) -> tuple[np.ndarray, ...] | None:
        """rgb_array mode: a frame (H, W, 3) uint8 per slot, slot i showing world i // N (its slots
        share the array); without a render mode nothing is drawn (None, with a warning)."""
        if self.render_mode is None:
            warnings.warn("PursuitVectorEnv was made without render_mode and draws nothing: pass "
                          "render_mode='rgb_array', or use `pursuit-mj render`", stacklevel=2)
            return None
        if self._frames is None:
            if self.closed:
                raise RuntimeError("render() called after close(): call reset() to draw again")
            raise RuntimeError("render() called before reset(): call reset() first")
        frames = [self._frames.draw(w) for w in range(self.n_worlds)]
        return tuple(frames[i // self.n_pursuers] for i in range(self.num_envs))

    def close_extras(self, **kwargs) -> None:
        """Free the renderer, if one was made, and the simulation (PursuitEnv.close); VectorEnv.close
        calls this once. reset() starts again: a new simulation, as if never closed."""
        if self._frames is not None:
            self._frames.close()
            self._frames = None
        self.batched.close()

    def _checked_actions(self, actions) -> np.ndarray:
        """`actions` as a (num_envs, 2) array of finite real numbers, or ValueError naming the slot
        (and its world and pursuer) of a bad value; values outside [-1, 1] are PursuitEnv's to clip."""
        try:
            a = plain_array(actions, "actions")
        except MaskedValues:
            raise
        except ValueError:  # nested lists of unequal lengths
            raise ValueError(f"actions: expected shape ({self.num_envs}, 2), got a ragged list") from None
        if a.dtype.kind not in "fiu":  # bools, text, objects (None) and complex numbers are no velocities
            raise ValueError(f"actions: expected real numbers, one row (vx, vy) per slot, got an array of dtype {a.dtype} "
                             f"({type(actions).__name__})")
        if a.shape != (self.num_envs, 2):
            raise ValueError(f"actions: expected shape ({self.num_envs}, 2), one row per slot ({self.n_worlds} worlds x "
                             f"{self.n_pursuers} pursuer{'s' if self.n_pursuers > 1 else ''}), got {a.shape}")
        bad = np.argwhere(~np.isfinite(a))
        if len(bad):
            slot, component = (int(i) for i in bad[0])
            raise ValueError(f"actions: non-finite value {a[slot, component]} at slot {slot} (world {slot // self.n_pursuers}, "
                             f"pursuer {slot % self.n_pursuers}), component {component}")
        return a

    def _push_frames(self) -> None:
        """rgb_array mode: the drones' positions to their trails (the renderer made the first time,
        but not after close(): a step then makes none, as close() would not free it; reset() does)."""
        if self.render_mode != "rgb_array" or (self._frames is None and self.closed):
            return
        if self._frames is None:
            from .render.live import LiveFrames

            self._frames = LiveFrames(self.batched, self._render_settings, "PursuitVectorEnv")
        self._frames.push()

    def _flat(self, obs: np.ndarray) -> np.ndarray:
        """(W, N, obs_dim) -> (num_envs, obs_dim), slot w * N + n."""
        return obs.reshape(self.num_envs, -1)


def _with_masks(values: dict[str, np.ndarray], mask: np.ndarray) -> dict[str, np.ndarray]:
    """gymnasium's vector info layout: each key beside its "_key" mask of the slots that have it
    (a copy each, as gymnasium's own infos have: a wrapper that edits one leaves the others)."""
    return {**values, **{f"_{k}": mask.copy() for k in values}}


def _checked_mode(mode: Any) -> AutoresetMode:
    """An AutoresetMode this env runs (NEXT_STEP, SAME_STEP), from the member or its value."""
    try:
        found = AutoresetMode(mode)
    except ValueError:
        found = None
    if found not in MODES:
        raise ValueError(f"autoreset_mode: expected one of {', '.join(f'AutoresetMode.{m.name} ({m.value!r})' for m in MODES)}, "
                         f"got {mode!r}")
    return found


def make_vector_env(num_envs: int, config: TaskConfig | Mapping | str | None = None, **kwargs) -> PursuitVectorEnv:
    """gymnasium.make_vec's entry point: a PursuitVectorEnv of `num_envs` slots, which must be a
    whole number of worlds (a multiple of config.n_pursuers); other keywords are PursuitVectorEnv's."""
    config = default_config() if config is None else task_config_from(config, f"{ENV_ID} config")
    n = config.n_pursuers
    if isinstance(num_envs, (bool, np.bool_)) or not isinstance(num_envs, (int, np.integer)) or num_envs < n or num_envs % n:
        raise ValueError(f"{ENV_ID} num_envs: expected a positive multiple of n_pursuers ({n}: one slot per pursuer of "
                         f"each world), got {num_envs!r}")
    if "max_episode_steps" in kwargs:  # what gymnasium users pass for a time limit
        raise ValueError(f"{ENV_ID} max_episode_steps: the task's own max_steps is the time limit (truncation): "
                         f"give config=default_config(max_steps=...)")
    if "n_worlds" in kwargs:
        raise ValueError(f"{ENV_ID}: give num_envs (n_worlds x n_pursuers), not n_worlds")
    return PursuitVectorEnv(config, n_worlds=int(num_envs) // n, **kwargs)


def _no_single_env(**kwargs):
    """gymnasium.make's entry point (and make_vec's "sync" / "async" modes): refused, saying what works."""
    raise ValueError(f"{ENV_ID} is a vector env with a slot per pursuer of each world: make it with "
                     f"gymnasium.make_vec({ENV_ID!r}, num_envs=...) (its default vector_entry_point mode), or one "
                     f"world as a PettingZoo env with pursuit_mj.pz_env.PursuitParallelEnv")


if ENV_ID not in gymnasium.registry:  # entry points by name: the spec then serialises (to_json, pickle) and outlives a reload
    gymnasium.register(ENV_ID, entry_point=f"{__name__}:_no_single_env", vector_entry_point=f"{__name__}:make_vector_env")
