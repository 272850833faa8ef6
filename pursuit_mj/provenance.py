"""Which code produced a result: package version, git commit (and whether the tree had local
changes), a hash of the source the packages run from, and a hash of the drone model, for the
metadata of saved results.

Kept results (an interrupted eval's rows, a study's evaluated cells) are matched on the
source hash, not the commit: a commit that changes only docs or tests keeps them, and a local
edit that is not committed, or an installed wheel without git, does not slip past."""

from __future__ import annotations

import functools
import hashlib
import importlib.util
import os
import subprocess
from importlib import metadata
from pathlib import Path

from .scene import DRONE_FILE
from .shipped import REPO_ROOT


def _git(*args: str) -> str | None:
    try:
        out = subprocess.run(["git", "-C", str(REPO_ROOT), *args], capture_output=True, text=True, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip() if out.returncode == 0 else None


SOURCE_PACKAGES = ("pursuit_mj", "train", "pursuit_cli")  # every package a command runs code from


#: folders under a package left out of its hash: the shipped policies (each model file is hashed
#: where it is used: model_sha256)
UNHASHED_FOLDERS = ("assets/pretrained",)


def _source_files(root: Path) -> list[Path]:
    """Every file under root, linked folders followed (pursuit_mj/assets/* are links in a git
    checkout and copies in a wheel: both must hash alike), less compiled caches and UNHASHED_FOLDERS."""
    files = []
    for folder, subfolders, names in os.walk(root, followlinks=True):
        subfolders[:] = [d for d in subfolders if d != "__pycache__"
                         and (Path(folder) / d).relative_to(root).as_posix() not in UNHASHED_FOLDERS]
        files += [Path(folder) / n for n in names if not n.endswith(".pyc")]
    return sorted(f for f in files if f.is_file())


def source_digest(folders: dict[str, Path]) -> str:
    """sha256 over every file under the named folders (path relative to its folder, then bytes),
    in sorted order (see _source_files for what is left out)."""
    h = hashlib.sha256()
    for name in sorted(folders):
        root = folders[name]
        for f in _source_files(root):
            rel = f"{name}/{f.relative_to(root).as_posix()}".encode()
            data = f.read_bytes()
            h.update(len(rel).to_bytes(8, "little") + rel + len(data).to_bytes(8, "little") + data)
    return h.hexdigest()


def _package_folder(name: str) -> Path | None:
    """Where a package's files are, without importing it (None if it cannot be found)."""
    try:
        spec = importlib.util.find_spec(name)
    except (ImportError, ValueError):
        return None
    locations = list(spec.submodule_search_locations or []) if spec is not None else []
    return Path(locations[0]) if locations else None


@functools.lru_cache(maxsize=1)
def source_sha256() -> str:
    """The hash of this installation's pursuit_mj, train and pursuit_cli sources (the assets:
    built-in layouts, task and train configs and the drone model included, the shipped policies
    not); computed once per process."""
    folders = {name: folder for name in SOURCE_PACKAGES if (folder := _package_folder(name)) is not None}
    return source_digest(folders)


def provenance() -> dict[str, object]:
    """{"version", "git_commit", "git_dirty", "source_sha256", "drone_model_sha256"}; git entries
    are None outside a git checkout (an installed wheel). git_dirty: tracked files differ from
    the commit. source_sha256: `source_sha256()`, what kept results are matched on."""
    try:
        version = metadata.version("pursuit-mj")
    except metadata.PackageNotFoundError:
        version = None
    commit = _git("rev-parse", "HEAD") if (REPO_ROOT / ".git").exists() else None
    dirty = None
    if commit is not None:
        status = _git("status", "--porcelain", "--untracked-files=no")
        dirty = None if status is None else bool(status)
    return {"version": version, "git_commit": commit, "git_dirty": dirty, "source_sha256": source_sha256(),
            "drone_model_sha256": hashlib.sha256(DRONE_FILE.read_bytes()).hexdigest()}
