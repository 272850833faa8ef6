"""A policy of one's own from a Python file, for the command line: `--policy FILE.py:NAME`.

NAME, defined in FILE, is called as NAME(config, seed) (a class or a function; config the
run's `TaskConfig`, seed the command's --seed) and must give a Policy (pursuit_mj.policy:
`name`, `reset`, `act`). The file runs as a module of its own, not as part of a package, so it
imports what it needs itself (numpy, pursuit_mj, torch). Every failure is a ValueError that
names the reference and, for an error raised in the file, the line it came from.
"""

from __future__ import annotations

from pathlib import Path

from .config import TaskConfig
from .policy import Policy
from .user_file import file_sha256, is_file_reference, load_named, made_by, split_reference


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


def load_policy_file(ref: str, config: TaskConfig, seed: int = 0, source: str = "--policy") -> Policy:
    """NAME(config, seed) from FILE for a FILE.py:NAME reference, checked to be a Policy with a
    `name` (the label tables and captions show)."""
    factory, path, name = load_named(ref, source)
    where = f"{source} {ref}"
    policy = made_by(factory, (config, seed), f"{name}(config, seed)", where, path, ("act", "reset"),
                     "a Policy: an object with name, reset(n_worlds, world_ids=None) and act(obs, spec) (docs/env_api.md)")
    label = getattr(policy, "name", None)
    if not isinstance(label, str) or not label.strip():
        raise ValueError(f"{where}: the policy {name}(config, seed) returned has no `name` text (tables and captions "
                         f"label it by that), got {label!r}")
    return policy
