"""A policy of one's own from a Python file, for the command line: `--policy FILE.py:NAME`.

NAME, defined in FILE, is called as NAME(config, seed) (a class or a function; config the
run's `TaskConfig`, seed the command's --seed) and must give a Policy (pursuit_mj.policy:
`name`, `reset`, `act`). The file runs as a module of its own, not as part of a package, so it
imports what it needs itself (numpy, pursuit_mj, torch). Every failure is a ValueError that
names the reference and, for an error raised in the file, the line it came from: while the file
loads and the policy is made, and later in its `reset` and `act` (FilePolicy), whose answers of
another shape, no real numbers, NaN or inf are refused naming the reference too.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from .config import TaskConfig
from .obs_spec import ObsSpec
from .policy import Policy, checked_actions
from .user_file import UserCodeError, file_sha256, is_file_reference, load_named, made_by, split_reference, what_and_where


def is_policy_file(ref: str) -> bool:
    """Whether `ref` has the form FILE.py:NAME (not whether the file exists)."""
    return is_file_reference(ref)


def policy_file_path(ref: str) -> Path:
    """The FILE of a FILE.py:NAME reference."""
    return Path(split_reference(ref, "policy")[0])


def policy_file_name(ref: str) -> str:
    """The NAME of a FILE.py:NAME reference (two factories of one file may give policies of one `name`)."""
    return split_reference(ref, "policy")[1]


def policy_file_sha256(ref: str) -> str:
    """sha256 of the file a FILE.py:NAME reference names (eval --resume checks it is unchanged)."""
    return file_sha256(ref, "policy")


class FilePolicy:
    """A Policy of one's own as its file made it, whose `reset` and `act` name the reference and
    the line of the file in one line (a UserCodeError) when they raise, as loading it does, not
    in a traceback through eval's or render's code. Every other attribute is the policy's own."""

    def __init__(self, policy: Any, where: str, path: Path):
        self.policy = policy
        self.where = where  # "--policy FILE.py:NAME"
        self.path = path
        self.name = policy.name

    def __getattr__(self, attr: str) -> Any:
        """The wrapped policy's attributes (has_shield, its own settings); only asked for those
        the wrapper lacks."""
        if attr in ("policy", "where", "path") or attr.startswith("__"):
            raise AttributeError(attr)  # not yet set (a copy being made): never the policy's
        return getattr(self.policy, attr)

    def reset(self, n_worlds: int, world_ids: np.ndarray | None = None) -> None:
        try:
            self.policy.reset(n_worlds, world_ids)
        except (Exception, SystemExit) as exc:  # the user's own code: say where it failed, in one line
            raise UserCodeError(f"{self.where}: reset(n_worlds, world_ids) raised {what_and_where(exc, self.path)}") from exc

    def act(self, obs: np.ndarray, spec: ObsSpec) -> np.ndarray:
        """What the policy's act returned, checked as eval checks actions (policy.checked_actions:
        float64 (W, N, 2), real and finite), naming the reference when it is not: the file a wrong
        shape or a NaN came from, as for an exception raised in it. It acts on a copy of obs: what
        it writes into its observations (an in-place normalisation) changes nothing that its caller
        reads after it (a shield judges walls and teammates from obs)."""
        try:
            raw = self.policy.act(np.array(obs), spec)
        except (Exception, SystemExit) as exc:
            raise UserCodeError(f"{self.where}: act(obs, spec) raised {what_and_where(exc, self.path)}") from exc
        W, N = np.shape(obs)[:2]
        return checked_actions(raw, W, N, self.where)


def load_policy_file(ref: str, config: TaskConfig, seed: int = 0, source: str = "--policy") -> Policy:
    """NAME(config, seed) from FILE for a FILE.py:NAME reference, checked to be a Policy with a
    `name` (the label tables and captions show), as a FilePolicy: an exception in its reset or
    act is a ValueError naming `source`, the reference and the line."""
    factory, path, name = load_named(ref, source)
    where = f"{source} {ref}"
    policy = made_by(factory, (config, seed), f"{name}(config, seed)", where, path, ("act", "reset"),
                     "a Policy: an object with name, reset(n_worlds, world_ids=None) and act(obs, spec) (docs/env_api.md)")
    label = getattr(policy, "name", None)
    if not isinstance(label, str) or not label.strip():
        raise ValueError(f"{where}: the policy {name}(config, seed) returned has no `name` text (tables and captions "
                         f"label it by that), got {label!r}")
    return FilePolicy(policy, where, path)
