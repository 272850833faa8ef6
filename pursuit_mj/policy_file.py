"""A policy of one's own from a Python file, for the command line: `--policy FILE.py:NAME`.

NAME, defined in FILE, is called as NAME(config, seed) (a class or a function; config the
run's `TaskConfig`, seed the command's --seed) and must give a Policy (pursuit_mj.policy:
`name`, `reset`, `act`). The file runs as a module of its own, not as part of a package, so it
imports what it needs itself (numpy, pursuit_mj, torch). Every failure is a ValueError that
names the reference and, for an error raised in the file, the line it came from.
"""

from __future__ import annotations

import hashlib
import importlib.util
import re
import sys
import traceback
from pathlib import Path

from .config import TaskConfig
from .policy import Policy

_REFERENCE = re.compile(r"^(?P<path>.+\.py):(?P<name>[A-Za-z_][A-Za-z0-9_]*)$")


def is_policy_file(ref: str) -> bool:
    """Whether `ref` has the form FILE.py:NAME (not whether the file exists)."""
    return _REFERENCE.match(ref) is not None


def policy_file_path(ref: str) -> Path:
    """The FILE of a FILE.py:NAME reference."""
    return Path(_split(ref, "policy")[0])


def policy_file_name(ref: str) -> str:
    """The NAME of a FILE.py:NAME reference (two factories of one file may give policies of one `name`)."""
    return _split(ref, "policy")[1]


def policy_file_sha256(ref: str) -> str:
    """sha256 of the file a FILE.py:NAME reference names (eval --resume checks it is unchanged)."""
    return hashlib.sha256(policy_file_path(ref).read_bytes()).hexdigest()


def load_policy_file(ref: str, config: TaskConfig, seed: int = 0, source: str = "--policy") -> Policy:
    """NAME(config, seed) from FILE for a FILE.py:NAME reference, checked to be a Policy with a
    `name` (the label tables and captions show)."""
    path_text, name = _split(ref, source)
    where = f"{source} {ref}"
    path = Path(path_text)
    if not path.is_file():
        raise ValueError(f"{where}: no file {path} (give FILE.py:NAME, FILE relative to the current folder or absolute)")
    module = _run_file(path, where)
    factory = getattr(module, name, None)
    if not callable(factory):
        defined = sorted(k for k, v in vars(module).items() if callable(v) and getattr(v, "__module__", None) == module.__name__)
        raise ValueError(f"{where}: {path} defines no class or function {name!r} (it defines: {', '.join(defined) or 'none'})")
    try:
        policy = factory(config, seed)
    except (Exception, SystemExit) as exc:  # the user's own code: say where it failed, in one line
        raise ValueError(f"{where}: {name}(config, seed) raised {_what_and_where(exc, path)}") from exc
    missing = [m for m in ("act", "reset") if not callable(getattr(policy, m, None))]
    if missing or isinstance(policy, type):
        what = (f"the class {policy.__name__}, not an instance of it" if isinstance(policy, type)
                else f"{policy!r}, which has no {' or '.join(missing)} method")
        raise ValueError(f"{where}: {name}(config, seed) returned {what}; it must return a Policy: an object with "
                         f"name, reset(n_worlds, world_ids=None) and act(obs, spec) (docs/env_api.md)")
    label = getattr(policy, "name", None)
    if not isinstance(label, str) or not label.strip():
        raise ValueError(f"{where}: the policy {name}(config, seed) returned has no `name` text (tables and captions "
                         f"label it by that), got {label!r}")
    return policy


def _split(ref: str, source: str) -> tuple[str, str]:
    match = _REFERENCE.match(ref)
    if match is None:
        raise ValueError(f"{source} {ref!r}: expected FILE.py:NAME (a Python file and the class or function in it)")
    return match["path"], match["name"]


def _run_file(path: Path, where: str):
    """The module of `path`, run once; ValueError naming the line of an error raised in it."""
    module_name = "pursuit_policy_" + hashlib.sha256(str(path.resolve()).encode()).hexdigest()[:12]
    spec = importlib.util.spec_from_file_location(module_name, path)
    if spec is None or spec.loader is None:
        raise ValueError(f"{where}: {path} cannot be loaded as a Python module")
    module = importlib.util.module_from_spec(spec)
    sys.modules[module_name] = module  # dataclasses and pickling look their module up by name
    try:
        spec.loader.exec_module(module)
    except (Exception, SystemExit) as exc:  # sys.exit() at a script's top level would end the command silently
        del sys.modules[module_name]
        raise ValueError(f"{where}: running {path} raised {_what_and_where(exc, path)}") from exc
    return module


def _what_and_where(exc: BaseException, path: Path) -> str:
    """'TypeError: ... (at FILE:LINE)', the deepest line of `path` in the traceback when there is one."""
    frames = [f for f in traceback.extract_tb(exc.__traceback__) if Path(f.filename).resolve() == path.resolve()]
    if isinstance(exc, SyntaxError) and exc.lineno is not None:
        return f"SyntaxError: {exc.msg} (at {path}:{exc.lineno})"
    at = f" (at {path}:{frames[-1].lineno})" if frames else ""
    return f"{type(exc).__name__}: {exc}{at}"
