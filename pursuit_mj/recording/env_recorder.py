"""Record the episodes of any loop over a multi-world `PursuitEnv` (evaluation, validation) into rerun.

    rec = EnvRecorder(RerunEpisodeRecording("eval.rrd"), env, label={"policy": "heuristic"}, max_episodes=20)
    obs = env.reset();                 rec.started(range(env.n_worlds))
    obs, r, term, trunc, info = env.step(actions);   rec.stepped(info)
    obs = env.reset_worlds(ids);       rec.started(ids)
    rec.recording.close()

The environment must run with auto_reset=False: with auto-reset a finished world's last
state is replaced by the next episode's first before a recorder can read it. Only reads
`env.snapshot`, so the loop's episodes are unchanged.
"""

from __future__ import annotations

from typing import Iterable, Mapping

import numpy as np

from .rerun_episodes import EpisodeBuffer, RerunEpisodeRecording


class EnvRecorder:
    """Buffers every world's current episode and sends it when the environment reports it finished."""

    def __init__(self, recording: RerunEpisodeRecording, env, label: dict | None = None, max_episodes: int | None = None):
        if not callable(getattr(recording, "add_episode", None)):
            raise ValueError(f"EnvRecorder recording: expected a RerunEpisodeRecording, got {recording!r}")
        if not hasattr(env, "auto_reset") or not callable(getattr(env, "snapshot", None)):
            raise ValueError(f"EnvRecorder env: expected a PursuitEnv, got {type(env).__name__}")
        if env.auto_reset:
            raise ValueError("EnvRecorder: the environment must run with auto_reset=False (the final states are lost otherwise)")
        if max_episodes is not None and (isinstance(max_episodes, bool) or not isinstance(max_episodes, (int, np.integer))
                                         or max_episodes < 1):
            raise ValueError(f"max_episodes: expected an integer >= 1 or None, got {max_episodes!r}")
        if label is not None and not isinstance(label, Mapping):
            raise ValueError(f"EnvRecorder label: expected a mapping such as {{'policy': 'heuristic'}}, got {label!r}")
        self.recording = recording
        self.env = env
        self.label = dict(label or {})
        self.max_episodes = max_episodes
        self._buffers: dict[int, EpisodeBuffer] = {}
        self._claimed = 0  # episodes started under recording (finished or not)

    def started(self, world_ids: Iterable[int]) -> None:
        """The listed worlds were (re)set: begin buffering their new episodes (while the quota lasts)."""
        for w in np.asarray(list(world_ids), dtype=np.int64):
            self._buffers.pop(int(w), None)
            if self.max_episodes is not None and self._claimed >= self.max_episodes:
                continue
            # started: the order the episodes began in; in `eval` (pursuit_mj.evaluation.run_episodes
            # starts them in table order) it is the episode's index k among the row's episodes
            buf = EpisodeBuffer(dict(self.label, started=self._claimed))
            buf.append(self.env.snapshot(int(w)))
            self._buffers[int(w)] = buf
            self._claimed += 1

    def stepped(self, info: dict) -> None:
        """After env.step: add each recorded world's new state; send the episodes that just finished."""
        finished = {rec.world: rec for rec in info["episodes"]}
        for w, buf in list(self._buffers.items()):
            if self.env.done[w] and w not in finished:
                continue  # frozen since an earlier step, waiting for reset_worlds
            buf.append(self.env.snapshot(w))
            if w in finished:
                self.recording.add_episode(buf, finished[w])
                del self._buffers[w]

    @property
    def pending(self) -> int:
        """Episodes being buffered but not finished yet."""
        return len(self._buffers)
