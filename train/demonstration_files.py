"""DAgger's dataset on disk, so that a resumed run keeps its demonstrations (train/imitation.py).

Before each 'last' checkpoint the pairs added since the previous one go to a file of their own,
RUN/demonstrations/u{update}-p{first}-n{count}.pt (update: the checkpoint's; first: the index of
its first pair among all pairs ever added; tensors only, read without unpickling code). Files
that only hold pairs the dataset has since dropped are removed once the checkpoint is written,
so the folder holds about one dataset (`imitation.dataset_size` x (observation size + 2) x 4 bytes at most).

A resume from last.pt at update U removes the files of later updates (written before a crash
cut their checkpoint short) and refills the dataset with the newest pairs of the rest, as the
checkpoint counted them. Files that are missing or damaged cost their pairs and the older ones,
and the resume says how many it kept.
"""

from __future__ import annotations

import re
from pathlib import Path

import torch

from .checkpoint import save_checkpoint
from .imitation import Demonstrations

FOLDER = "demonstrations"
_NAME = re.compile(r"u(\d+)-p(\d+)-n(\d+)\.pt")


class DemonstrationFiles:
    """The demonstrations folder of one run."""

    def __init__(self, run_dir: Path):
        self.folder = Path(run_dir) / FOLDER

    def _files(self) -> list[tuple[int, int, int, Path]]:
        """(update, first, count, path) of every file, by first pair."""
        if not self.folder.is_dir():
            return []
        found = [(int(m[1]), int(m[2]), int(m[3]), p) for p in self.folder.iterdir() if (m := _NAME.fullmatch(p.name))]
        return sorted(found, key=lambda f: (f[1], f[0]))

    def save(self, demos: Demonstrations, update: int) -> None:
        """Write the pairs added since the last save (ValueError naming the file if it cannot be).
        Before the checkpoint of `update`; `prune` after it."""
        first, obs, actions = demos.unsaved()
        if obs.shape[0]:
            self.folder.mkdir(parents=True, exist_ok=True)
            path = self.folder / f"u{update:07d}-p{first:012d}-n{obs.shape[0]}.pt"
            save_checkpoint(path, {"first": first, "obs": obs, "actions": actions})
        demos.mark_saved()

    def prune(self, demos: Demonstrations) -> None:
        """Remove the files holding only pairs `demos` has dropped: once the checkpoint that counts
        them no more is written (before it, a crash would resume from one that needs them)."""
        oldest_held = demos.total - demos.size
        for _, start, count, path in self._files():
            if start + count <= oldest_held:
                path.unlink(missing_ok=True)

    def restore(self, demos: Demonstrations, update: int, total: int) -> int:
        """Refill `demos` with the newest pairs of the files up to `update`, of `total` ever added
        at that checkpoint; returns how many pairs it holds now."""
        files = []
        for upd, start, count, path in self._files():
            if upd > update or start + count > total:  # written after the checkpoint: its pairs are not the run's
                path.unlink(missing_ok=True)
            else:
                files.append((start, count, path))
        pieces, need = [], total  # gathered newest first, each ending where the next newer one starts
        for start, count, path in reversed(files):
            if need <= total - demos.capacity or start + count != need:
                break
            pair = _read(path, count, demos.obs.shape[1])
            if pair is None:
                break
            pieces.append(pair)
            need = start
        if not pieces:
            demos.refill(demos.obs[:0], demos.actions[:0], total)
            return 0
        obs = torch.cat([p[0] for p in reversed(pieces)])[-demos.capacity:]
        actions = torch.cat([p[1] for p in reversed(pieces)])[-demos.capacity:]
        demos.refill(obs, actions, total)
        return obs.shape[0]


def _read(path: Path, count: int, obs_dim: int) -> tuple[torch.Tensor, torch.Tensor] | None:
    """obs (count, obs_dim) and actions (count, 2) of one file; None if it is damaged or not one."""
    try:
        data = torch.load(path, map_location="cpu", weights_only=True)
        obs, actions = data["obs"], data["actions"]
    except Exception:  # a damaged file of any kind costs its pairs, not the resume
        return None
    if not (torch.is_tensor(obs) and torch.is_tensor(actions) and obs.shape == (count, obs_dim)
            and actions.shape == (count, 2) and obs.dtype == actions.dtype == torch.float32):
        return None
    return obs, actions
