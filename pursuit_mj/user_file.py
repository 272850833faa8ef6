"""Code of one's own from a Python file, for the command line: references of the form FILE.py:NAME.

The file runs as a module of its own, not as part of a package, so it imports what it needs
itself (numpy, pursuit_mj, torch). Every failure is a ValueError that names where the
reference came from (a flag, a config key) and, for an error raised in the file, the line.
`--policy FILE.py:NAME` (pursuit_mj.policy_file) and `--reward FILE.py:NAME`
(pursuit_mj.custom_rewards) read their files through here.
"""

from __future__ import annotations

import hashlib
import importlib.util
import re
import sys
import traceback
from pathlib import Path
from typing import Any

import numpy as np

class UserCodeError(ValueError):
    """Code of one's own (a reward term, an evader model) failed or answered what it must not: said in
    one line naming where it came from, wherever it runs (a rollout worker sends it back as it is)."""


_REFERENCE = re.compile(r"^(?P<path>.+\.py):(?P<name>[A-Za-z_][A-Za-z0-9_]*)$")


def is_file_reference(ref: str) -> bool:
    """Whether `ref` has the form FILE.py:NAME (not whether the file exists)."""
    return isinstance(ref, str) and _REFERENCE.match(ref) is not None


def split_reference(ref: str, source: str, what: str = "the class or function in it") -> tuple[str, str]:
    """(FILE, NAME) of a FILE.py:NAME reference; ValueError naming `source` for another form."""
    match = _REFERENCE.match(ref) if isinstance(ref, str) else None
    if match is None:
        raise ValueError(f"{source} {ref!r}: expected FILE.py:NAME (a Python file and {what})")
    return match["path"], match["name"]


def file_sha256(ref: str, source: str) -> str:
    """sha256 of the file a FILE.py:NAME reference names (a resume checks it is unchanged)."""
    return hashlib.sha256(Path(split_reference(ref, source)[0]).read_bytes()).hexdigest()


def load_named(ref: str, source: str, what: str = "class or function") -> tuple[Any, Path, str]:
    """(the object NAME in FILE, FILE's path, NAME) for a FILE.py:NAME reference, checked to be
    callable; ValueError naming `source` and `ref` for a missing file, an error raised while the
    file runs, or a NAME it lacks (the message lists the callables it defines)."""
    path_text, name = split_reference(ref, source)
    where = f"{source} {ref}"
    path = Path(path_text)
    if path.is_dir():
        raise ValueError(f"{where}: {path} is a folder, not a Python file")
    if not path.is_file():
        raise ValueError(f"{where}: no file {path} (give FILE.py:NAME, FILE relative to the current folder or absolute)")
    module = _run_file(path, where)
    found = getattr(module, name, None)
    if found is not None and not callable(found):  # there, but a number, a text ...: not 'missing'
        raise ValueError(f"{where}: {path} binds {name} to {_a(type(found).__name__)}, not a {what}")
    if not callable(found):
        defined = sorted(k for k, v in vars(module).items() if callable(v) and getattr(v, "__module__", None) == module.__name__)
        raise ValueError(f"{where}: {path} defines no {what} {name!r} (it defines: {', '.join(defined) or 'none'})")
    return found, path, name


def _a(noun: str) -> str:
    """'an int', 'a str'."""
    return f"{'an' if noun[:1].lower() in 'aeiou' else 'a'} {noun}"


def _run_file(path: Path, where: str):
    """The module of `path`, run once; ValueError naming the line of an error raised in it."""
    module_name = "pursuit_user_" + hashlib.sha256(str(path.resolve()).encode()).hexdigest()[:12]
    spec = importlib.util.spec_from_file_location(module_name, path)
    if spec is None or spec.loader is None:
        raise ValueError(f"{where}: {path} cannot be loaded as a Python module")
    module = importlib.util.module_from_spec(spec)
    sys.modules[module_name] = module  # dataclasses and pickling look their module up by name
    try:
        spec.loader.exec_module(module)
    except (Exception, SystemExit) as exc:  # sys.exit() at a script's top level would end the command silently
        del sys.modules[module_name]
        raise ValueError(f"{where}: running {path} raised {what_and_where(exc, path)}") from exc
    return module


def what_and_where(exc: BaseException, path: Path | None) -> str:
    """'TypeError: ... (at FILE:LINE)', the deepest line of `path` in the traceback when there is
    one (of any file for path None: code not loaded from a file of its own)."""
    frames = [f for f in traceback.extract_tb(exc.__traceback__) if path is None or Path(f.filename).resolve() == path.resolve()]
    if isinstance(exc, SyntaxError) and exc.lineno is not None and path is not None:
        return f"SyntaxError: {exc.msg} (at {path}:{exc.lineno})"
    at = f" (at {path or frames[-1].filename}:{frames[-1].lineno})" if frames else ""
    return f"{type(exc).__name__}: {exc}{at}"


def made_by(factory, args: tuple, call: str, where: str, path: Path, methods: tuple[str, ...], must: str) -> Any:
    """factory(*args), the object user code makes, checked to be an instance with callable
    `methods`; ValueError naming `where` and `call` ("NAME(config, seed)") for an exception in
    the factory (with its line in `path`), or a result that is a class or lacks a method (`must`
    says what it must return instead)."""
    try:
        made = factory(*args)
    except (Exception, SystemExit) as exc:  # the user's own code: say where it failed, in one line
        raise ValueError(f"{where}: {call} raised {what_and_where(exc, path)}") from exc
    missing = [m for m in methods if not callable(getattr(made, m, None))]
    if missing or isinstance(made, type):
        what = (f"the class {made.__name__}, not an instance of it" if isinstance(made, type)
                else f"{made!r}, which has no {' or '.join(missing)} method")
        raise ValueError(f"{where}: {call} returned {what}; it must return {must}")
    return made


def _shown(value: Any, limit: int = 60) -> str:
    """`value` for a one-line error: None as None, anything else as its type and a short repr."""
    if value is None:
        return "None"
    text = repr(value)
    return f"{type(value).__name__} {text if len(text) <= limit else text[:limit] + '...'}"


def checked_real_array(raw: Any, shape: tuple[int, ...], said: str, axes: str, index: str, kinds: str = "fiu",
                       counted: np.ndarray | None = None) -> np.ndarray:
    """What user code returned, as float64 of `shape`; UserCodeError starting with `said` ("F: reward
    term 'x'") for anything else: no array, no real numbers (dtype kinds `kinds`), another shape
    (`axes` names the expected one's axes), NaN or inf (at the `index` named axes) where `counted`
    (bool, the shape's leading axes) is True, everywhere without it. Read as the env reads actions
    (env.plain_array): a torch tensor by its values (grad, half precision), a masked array with
    masked entries refused (its hidden values would be used as if given)."""
    from .env import MaskedValues, plain_array  # not at the top: the env imports this module

    try:
        values = plain_array(raw, f"{said} returned")
    except MaskedValues as exc:
        raise UserCodeError(str(exc)) from None
    except Exception as exc:  # noqa: BLE001 - what it returned is the user's; say what it was
        raise UserCodeError(f"{said} returned {type(raw).__name__}, not an array ({exc})") from None
    if values.dtype.kind == "O" and values.ndim == 0:  # None, a dict, ...: name what it was
        raise UserCodeError(f"{said} returned {_shown(raw)}, not an array of real numbers")
    if values.dtype.kind not in kinds:
        raise UserCodeError(f"{said} returned an array of dtype {values.dtype}, not real numbers")
    if values.shape != shape:
        raise UserCodeError(f"{said} returned shape {values.shape}, expected {shape} {axes}")
    values = values.astype(np.float64)
    bad = ~np.isfinite(values)
    if counted is not None:
        bad &= counted.reshape(counted.shape + (1,) * (values.ndim - counted.ndim))
    if bad.any():
        at = tuple(int(i) for i in np.argwhere(bad)[0])
        raise UserCodeError(f"{said} returned {values[at]} at {index} {at}")
    return values
