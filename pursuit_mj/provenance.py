"""Which code produced a result: package version, git commit (and whether the tree had local
changes), and a hash of the drone model, for the metadata of saved results."""

from __future__ import annotations

import hashlib
import subprocess
from importlib import metadata

from .scene import DRONE_FILE
from .shipped import REPO_ROOT


def _git(*args: str) -> str | None:
    try:
        out = subprocess.run(["git", "-C", str(REPO_ROOT), *args], capture_output=True, text=True, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip() if out.returncode == 0 else None


def provenance() -> dict[str, object]:
    """{"version", "git_commit", "git_dirty", "drone_model_sha256"}; git entries are None outside
    a git checkout (an installed wheel). git_dirty: tracked files differ from the commit."""
    try:
        version = metadata.version("pursuit-mj")
    except metadata.PackageNotFoundError:
        version = None
    commit = _git("rev-parse", "HEAD") if (REPO_ROOT / ".git").exists() else None
    dirty = None
    if commit is not None:
        status = _git("status", "--porcelain", "--untracked-files=no")
        dirty = None if status is None else bool(status)
    return {"version": version, "git_commit": commit, "git_dirty": dirty,
            "drone_model_sha256": hashlib.sha256(DRONE_FILE.read_bytes()).hexdigest()}
