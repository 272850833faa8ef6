"""Typed, frozen configs loaded from YAML and command-line overrides, validated loudly.

Every config in the project is a frozen dataclass whose fields may carry a `spec(...)`
metadata entry (allowed range, choices, help). One function, `build`, turns a plain dict
(from YAML or overrides) into such a dataclass, naming the source of any bad value.
"""

from __future__ import annotations

import dataclasses
import decimal
import difflib
import math
import re
import types
import typing
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence, TypeVar

import numpy as np
import yaml

T = TypeVar("T")


class ConfigError(ValueError):
    """A bad config key or value; the message names the key, the value and its source."""


class TaskValueError(ValueError):
    """A task value that passed the config's checks but that a user of it cannot work with
    (e.g. too few range readings for the heuristic team). The message is 'task KEY VALUE:
    REASON'; a CLI, which knows where the value came from, names that instead (`key`, `reason`)."""

    def __init__(self, key: str, value: Any, reason: str):
        super().__init__(f"task {key} {value}: {reason}")
        self.key, self.value, self.reason = key, value, reason


SHOWN_CHARS = 80  # how much of a bad value an error message quotes


def shown(value: Any) -> str:
    """repr(value) for an error message, cut to SHOWN_CHARS (a whole file read as one string
    would otherwise fill the terminal)."""
    text = repr(value)
    return text if len(text) <= SHOWN_CHARS else f"{text[:SHOWN_CHARS - 3]}... ({len(text)} characters)"


def spec(
    default: Any = dataclasses.MISSING,
    *,
    help: str = "",
    lo: float | None = None,
    hi: float | None = None,
    lo_open: bool = False,
    choices: Sequence[Any] | None = None,
    default_factory: Any = dataclasses.MISSING,
) -> Any:
    """A dataclass field with validation metadata.

    lo/hi bound numbers (inclusive unless lo_open); choices restricts to listed values.
    """
    meta = {"help": help, "lo": lo, "hi": hi, "lo_open": lo_open, "choices": choices}
    if default_factory is not dataclasses.MISSING:
        return dataclasses.field(default_factory=default_factory, metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def _type_hints(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls)


def _nested_keys(cls: type, name: str, prefix: str = "") -> list[str]:
    """Dotted keys ending in `name` in the sections (nested configs) of `cls`, at any depth."""
    out = []
    for f in dataclasses.fields(cls):
        hint = _type_hints(cls)[f.name]
        if dataclasses.is_dataclass(hint):
            if name in {g.name for g in dataclasses.fields(hint)}:
                out.append(f"{prefix}{f.name}.{name}")
            out += _nested_keys(hint, name, f"{prefix}{f.name}.")
    return out


def _suggest(name: str, valid: Sequence[str], cls: type | None = None, prefix: str = "") -> str:
    """' (did you mean ...?)' for an unknown key `name` among `valid`, the keys of `cls`: the key of
    that name in one of its sections first (evader_speed -> task.evader_speed), else a close spelling."""
    nested = _nested_keys(cls, name, prefix) if cls is not None else []
    if nested:
        return f" (did you mean {' or '.join(repr(k) for k in nested)}?)"
    close = difflib.get_close_matches(name, list(valid), n=1, cutoff=0.5)
    return f" (did you mean '{prefix}{close[0]}'?)" if close else f" (valid keys: {', '.join(sorted(valid))})"


def key_hint(name: Any, valid: Sequence[str]) -> str:
    """' (did you mean 'x'?)' for an unknown name among `valid` spelled close to one of them,
    else ' (valid: a, b, c)'."""
    close = difflib.get_close_matches(str(name), list(valid), n=1, cutoff=0.5)
    return f" (did you mean '{close[0]}'?)" if close else f" (valid: {', '.join(valid)})"


def _split_where(source: str) -> tuple[str, str]:
    """(where the values came from, the dotted section they belong to + '.') of an error's `source`:
    a nested section's values arrive with the source "f.yaml: key 'evader'", and their errors
    name the whole path ("f.yaml: key 'evader.panic_distance'") rather than one key after another."""
    head, sep, tail = source.rpartition(": key '")
    if sep and tail.endswith("'") and "'" not in tail[:-1]:
        return head, tail[:-1] + "."
    return source, ""


def _quoted_word(where: str) -> str:
    """For `where` of an override of one word ("--set name=no: key 'name'"): ", inside the shell's
    own quotes: --set 'name="no"'"; '' for a file or a value of more than a word."""
    found = re.match(r"^(--[\w-]+) ([\w.]+)=([A-Za-z]+): key '", where)
    if found is None:
        return ""
    flag, key, word = found.groups()
    return f", inside the shell's own quotes: {quoted_override(flag, key, word)}"


def key_where(source: str, name: str) -> str:
    """"source: key 'name'", with `name` joined to the section `source` names (_split_where)."""
    head, section = _split_where(source)
    return f"{head}: key '{section}{name}'"


def _coerce(value: Any, hint: Any, where: str) -> Any:
    """Check `value` against the type hint, allowing int -> float and list -> tuple."""
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if hint is Any:
        return value
    if origin in (typing.Union, types.UnionType):
        errors = []
        for option in args:
            try:
                return _coerce(value, option, where)
            except ConfigError as exc:
                errors.append(str(exc))
        words = {type(None): "null", int: "an integer", float: "a number", str: "a string", bool: "true or false"}
        names = " or ".join(words.get(a, getattr(a, "__name__", str(a))) for a in args)
        raise ConfigError(f"{where}: {value!r} is not {names}")
    if hint is type(None):
        if value is None:
            return None
        raise ConfigError(f"{where}: expected null, got {shown(value)}")
    if origin is typing.Literal:
        if value in args:
            return value
        raise ConfigError(f"{where}: {value!r} is not one of {list(args)}")
    if origin in (tuple, Sequence, list) or hint in (tuple, list):
        if not isinstance(value, (list, tuple)):
            how = f" (write it as {_as_list(value)})" if isinstance(value, str) and "," in value else ""
            raise ConfigError(f"{where}: expected a list, got {shown(value)}{how}")
        if origin is tuple and args and args[-1] is not Ellipsis:
            if len(args) != len(value):
                raise ConfigError(f"{where}: expected {len(args)} values, got {list(value)!r}")
            return tuple(_coerce(v, a, f"{where}[{i}]") for i, (v, a) in enumerate(zip(value, args)))
        inner = args[0] if args else Any
        return tuple(_coerce(v, inner, f"{where}[{i}]") for i, v in enumerate(value))
    if dataclasses.is_dataclass(hint):
        if isinstance(value, hint):  # made directly: its values checked as if read here
            return build(hint, to_dict(value), where)
        if not isinstance(value, Mapping):
            raise ConfigError(f"{where}: expected a mapping of {hint.__name__} keys, got {shown(value)}")
        return build(hint, value, where)
    if hint is bool:
        if isinstance(value, bool):
            return value
        raise ConfigError(f"{where}: expected true or false, got {shown(value)}")
    if hint is int:
        if isinstance(value, (int, np.integer)) and not isinstance(value, bool):
            return int(value)
        if isinstance(value, (float, np.floating)) and float(value).is_integer():
            return int(value)  # a count written 2e4 or 20000.0, as the CLI flags take it
        raise ConfigError(f"{where}: expected an integer, got {shown(value)}")
    if hint is float:
        if isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool):
            if not math.isfinite(float(value)):
                raise ConfigError(f"{where}: expected a finite number, got {shown(value)}")
            return float(value)
        raise ConfigError(f"{where}: expected a number, got {shown(value)}")
    if hint is str:
        if isinstance(value, str):
            return value
        if isinstance(value, Path):  # a layout file given as a Path in Python
            return str(value)
        if isinstance(value, bool):  # name=no: the word typed is not the value shown
            raise ConfigError(f"{where}: expected a string, got {shown(value)} (YAML reads yes/no/on/off/true/false "
                              f"as booleans; quote the word to keep it as text{_quoted_word(where)})")
        raise ConfigError(f"{where}: expected a string, got {shown(value)}")
    if isinstance(hint, type) and isinstance(value, hint):
        return value
    raise ConfigError(f"{where}: {value!r} does not fit type {hint}")


def _as_list(text: str) -> str:
    """A comma-separated value as the YAML list it was meant to be: '64,64' and '(64,64)' -> '[64,64]'."""
    inner = text.strip()
    if inner.startswith("(") and inner.endswith(")"):
        inner = inner[1:-1]
    return f"[{inner}]"


def _check_range(value: Any, meta: Mapping[str, Any], where: str) -> None:
    choices = meta.get("choices")
    if choices is not None and value not in choices:
        raise ConfigError(f"{where}: {value!r} is not one of {list(choices)}")
    lo, hi = meta.get("lo"), meta.get("hi")
    if not isinstance(value, (int, float)) or isinstance(value, bool):
        return
    if lo is not None:
        bad = value <= lo if meta.get("lo_open") else value < lo
        if bad:
            op = ">" if meta.get("lo_open") else ">="
            raise ConfigError(f"{where}: {number_text(value)} is out of range (must be {op} {lo})")
    if hi is not None and value > hi:
        raise ConfigError(f"{where}: {number_text(value)} is out of range (must be <= {hi})")


def number_text(value: int | float) -> str:
    """A number for an error message: a whole number of more than 15 digits (1e300 typed for a
    count) in %g notation, 6 significant digits (1e+30; also past a float's range, 1e+400),
    anything else as repr gives it."""
    if not (isinstance(value, int) and abs(value) >= 10**15):
        return repr(value)
    return format(decimal.Context(prec=6).create_decimal(value).normalize(), "g")  # exact: no float overflow


def _known_fields(cls: type, values: Mapping[str, Any], source: str) -> dict[str, dataclasses.Field]:
    """The dataclass fields of `cls` by name; ConfigError (with a close key suggested) if
    `values` has a key that is not one of them."""
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = [k for k in values if k not in fields]
    if unknown:
        key = unknown[0]
        head, section = _split_where(source)
        raise ConfigError(f"{head}: unknown key '{section}{key}'{_suggest(str(key), list(fields), cls, section)}")
    return fields


def build(cls: type[T], values: Mapping[str, Any] | None, source: str = "config") -> T:
    """Make a `cls` from a (possibly partial, possibly nested) mapping, validating each value.

    Raises ConfigError naming the key, the bad value and `source` (file, flag ...).
    """
    values = dict(values or {})
    fields = _known_fields(cls, values, source)
    hints = _type_hints(cls)
    kwargs = {}
    for name, value in values.items():
        where = key_where(source, name)
        coerced = _coerce(value, hints[name], where)
        _check_range(coerced, fields[name].metadata, where)
        kwargs[name] = coerced
    try:
        obj = cls(**kwargs)
    except TypeError as exc:  # a required field was not given
        raise ConfigError(f"{source}: {exc}") from None
    validate = getattr(obj, "validate", None)
    if callable(validate):
        validate(source)
    return obj


def to_dict(obj: Any) -> Any:
    """A plain (YAML-ready) dict of a config dataclass; tuples become lists."""
    if dataclasses.is_dataclass(obj):
        return {f.name: to_dict(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, (list, tuple)):
        return [to_dict(v) for v in obj]
    return obj


def parse_override(text: str, source: str) -> tuple[list[str], Any]:
    """Split 'a.b=value' into (['a', 'b'], parsed YAML value)."""
    if "=" not in text:
        raise ConfigError(f"{source}: '{text}' is not of the form key=value")
    key, raw = text.split("=", 1)
    key = key.strip()
    if not key:
        raise ConfigError(f"{source}: '{text}' has an empty key")
    if "" in key.split("."):
        raise ConfigError(f"{source}: '{key}' has an empty part (the keys of nested sections are joined by single dots)")
    try:
        value = safe_load(raw) if raw.strip() else ""
    except yaml.YAMLError as exc:
        raise ConfigError(f"{source}: value of '{key}' is not valid YAML: {raw!r} ({yaml_error_text(exc)})") from exc
    comment = _comment_start(raw)
    if comment is not None:  # YAML drops it: --set random_obstacles=#3 was null, 'name=run #2' was 'run'
        raise ConfigError(f"{source}: the value of '{key}' holds a YAML comment ({raw[comment:].strip()!r} is dropped); "
                          f"quote the value to keep the '#', inside the shell's own quotes: "
                          f"{quoted_override(source, key, raw.strip())}")
    return key.split("."), value


def quoted_override(source: str, key: str, text: str) -> str:
    """The override KEY=TEXT with TEXT as a YAML string, as typed in a shell: --set 'KEY="TEXT"'
    (the shell takes away one pair of quotes, YAML the other); the flag is the first word of
    `source` where that is a flag ('--set name=run #2'), else --set."""
    flag = source.split(" ", 1)[0] if source.startswith("--") else "--set"
    if "'" in text or '"' in text or "\\" in text:  # no one form fits every shell and YAML: say it in words
        return f"{flag} '{key}=\"...\"' (the value as a double-quoted YAML string)"
    return f"{flag} '{key}=\"{text}\"'"


def _comment_start(raw: str) -> int | None:
    """Where a comment starts in the YAML text `raw` (valid YAML): a '#' after its last token, else None."""
    tokens = [t for t in yaml.scan(raw, Loader=_UniqueKeyLoader)
              if not isinstance(t, (yaml.StreamStartToken, yaml.StreamEndToken))]
    end = tokens[-1].end_mark.index if tokens else 0
    found = raw.find("#", end)
    return None if found < 0 else found


def merge(base: Mapping[str, Any], path: list[str], value: Any) -> dict[str, Any]:
    """Return a copy of `base` with `value` set at the nested key `path`."""
    out = dict(base)
    if len(path) == 1:
        out[path[0]] = value
        return out
    child = out.get(path[0]) or {}
    if not isinstance(child, Mapping):
        child = to_dict(child)
    out[path[0]] = merge(child, path[1:], value)
    return out


def yaml_error_text(exc: yaml.YAMLError) -> str:
    """A YAML parse error in one line: 'line L, column C: what is wrong' (1-based, as editors count)."""
    mark = getattr(exc, "problem_mark", None) or getattr(exc, "context_mark", None)
    if mark is None and getattr(exc, "position", None) is not None:  # a character YAML does not allow (the reader's error)
        return f"character {exc.position + 1}: {exc}".split("\n")[0]
    problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
    context = getattr(exc, "context", None)
    what = f"{problem} ({context})" if context else problem
    return f"line {mark.line + 1}, column {mark.column + 1}: {what}" if mark is not None else what


class _UniqueKeyLoader(yaml.SafeLoader):
    """yaml.SafeLoader that refuses a key given twice in one mapping (PyYAML keeps the last silently)."""

    def construct_mapping(self, node, deep=False):
        first_line: dict[Any, int] = {}
        for key_node, _ in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":  # '<<: *base' merges keys; the keys beside it win
                continue
            key = self.construct_object(key_node, deep=deep)
            try:
                duplicate = key in first_line
            except TypeError:  # an unhashable key: SafeLoader reports it
                break
            if duplicate:
                raise yaml.constructor.ConstructorError(
                    None, None, f"key {key!r} given twice (first on line {first_line[key] + 1})", key_node.start_mark)
            first_line[key] = key_node.start_mark.line
        return super().construct_mapping(node, deep)


def _construct_int(loader: yaml.SafeLoader, node: yaml.ScalarNode) -> int | str:
    """YAML 1.1 reads 010 as octal 8; YAML 1.2 and every user mean ten (0x10 and 0b10 keep their bases).
    YAML 1.1 reads 1:30 as 90 (base 60); YAML 1.2 reads a string, which a number key then refuses."""
    text = loader.construct_scalar(node).replace("_", "")
    if ":" in text:
        return loader.construct_scalar(node)
    if re.fullmatch(r"[-+]?0[0-9]+", text):
        return int(text, 10)
    return loader.construct_yaml_int(node)


def _construct_float(loader: yaml.SafeLoader, node: yaml.ScalarNode) -> float | str:
    """As YAML 1.1 floats, except base 60 (1:30.5), which YAML 1.2 reads as a string."""
    if ":" in loader.construct_scalar(node):
        return loader.construct_scalar(node)
    return loader.construct_yaml_float(node)


_UniqueKeyLoader.add_constructor("tag:yaml.org,2002:int", _construct_int)
_UniqueKeyLoader.add_constructor("tag:yaml.org,2002:float", _construct_float)


class _Dumper(yaml.SafeDumper):
    """yaml.SafeDumper that quotes the strings _UniqueKeyLoader reads as numbers (a run named '1e6')."""


# YAML 1.1, which PyYAML follows, reads 1e6 and 1e-4 (no dot) as text; YAML 1.2 and every
# user mean a number
for _cls in (_UniqueKeyLoader, _Dumper):
    _cls.add_implicit_resolver(
        "tag:yaml.org,2002:float", re.compile(r"^[-+]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)[eE][-+]?[0-9]+$"), list("-+0123456789."))


def safe_load(text: str) -> Any:
    """yaml.safe_load, refusing duplicate keys."""
    return yaml.load(text, Loader=_UniqueKeyLoader)  # noqa: S506 - a SafeLoader subclass


def safe_dump(data: Any, **kwargs: Any) -> str:
    """yaml.safe_dump (same keyword arguments) whose text `safe_load` reads back as `data`:
    strings it would read as numbers (a name '1e6') are quoted."""
    return yaml.dump(data, Dumper=_Dumper, **kwargs)


def read_text(path: Path, source: str) -> str:
    """A file's text; ConfigError naming `source` when it is not UTF-8 text (an image, say)."""
    try:
        return path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{source}: not a text (YAML) file (byte {exc.start + 1} is not UTF-8)") from None
    except OSError as exc:  # no permission, a device that cannot be read, a name too long
        raise ConfigError(f"{source}: cannot read it ({exc.strerror or exc})") from None


def found_beside(ref: Any, file: str | Path) -> Any:
    """A file path read from the config file `file`: one that is relative, not a file from the
    current folder but one beside `file`, becomes that path (as the file's author meant it);
    anything else (not a string, found from here, found nowhere) is returned unchanged, so a
    path from the current folder keeps working."""
    if not isinstance(ref, str) or not ref or Path(ref).is_absolute() or Path(ref).is_file():
        return ref
    beside = Path(file).parent / ref
    return str(beside) if beside.is_file() else ref


def load_yaml(path: str | Path, source: str | None = None) -> dict[str, Any]:
    """Read a YAML mapping; a missing file or non-mapping content is a ConfigError."""
    path = Path(path)
    src = source or str(path)
    if not path.is_file():
        raise ConfigError(f"{src}: file not found: {path}")
    try:
        data = safe_load(read_text(path, src))
    except yaml.YAMLError as exc:
        raise ConfigError(f"{src}: not valid YAML, {yaml_error_text(exc)}") from None
    if data is None:
        return {}
    if not isinstance(data, Mapping):
        raise ConfigError(f"{src}: expected a mapping at the top level, got {type(data).__name__}")
    return dict(data)


def load(
    cls: type[T],
    files: Sequence[str | Path] = (),
    overrides: Sequence[str] = (),
    extra: Mapping[str, Any] | None = None,
    extra_source: str = "command line",
    read: Callable[[Path], dict[str, Any]] | None = None,
    base: Mapping[str, Any] | None = None,
    base_source: str = "defaults",
) -> T:
    """Defaults <- `base` <- each YAML file in order <- `extra` (flags) <- `--set` overrides.

    Each source's keys and values are checked as it is read, so an error names the source
    that holds the bad value; the checks across keys (validate) judge the whole, so a later
    source may repair what an earlier one left inconsistent (--set evader.panic_distance=3.5
    --set evader.calm_distance=5), and their error names the source after which the config
    stayed inconsistent. `read` reads a file (default load_yaml). `base`: values the caller
    has read and checked key by key already (a train config's files, with their task files),
    named `base_source` when the config stays inconsistent from them on."""
    merged: dict[str, Any] = dict(base or {})
    stages: list[tuple[str, dict[str, Any]]] = [(base_source, merged)] if merged else []  # (source, merged after it)
    for f in files:
        data = (read or load_yaml)(f)
        check_values(cls, data, str(f))
        merged = _deep_update(merged, data)
        stages.append((str(f), merged))
    if extra:
        check_values(cls, extra, extra_source)
        merged = _deep_update(merged, dict(extra))
        stages.append((extra_source, merged))
    for text in overrides:
        source = f"--set {text}"
        path, value = parse_override(text, source)
        _check_path(cls, path, source)
        check_values(cls, merge({}, path, value), source)
        merged = _deep_update(merged, merge({}, path, value))  # a mapping value updates its section, as a file does
        stages.append((source, merged))
    try:
        return build(cls, merged, stages[-1][0] if stages else "defaults")
    except ConfigError:
        if len(stages) < 2:
            raise
    blamed = 0  # the first source after which every prefix stays inconsistent
    for i in range(len(stages) - 2, -1, -1):
        try:
            build(cls, stages[i][1], stages[i][0])
        except ConfigError:
            continue
        blamed = i + 1
        break
    return build(cls, merged, stages[blamed][0])


def check_values(cls: type, values: Mapping[str, Any], source: str) -> None:
    """Check the keys and values of a partial mapping for `cls` one by one (unknown keys, types,
    ranges), nested configs included; the checks across keys wait for the whole (see `load`)."""
    fields = _known_fields(cls, values, source)
    hints = _type_hints(cls)
    for name, value in values.items():
        where = key_where(source, name)
        if dataclasses.is_dataclass(hints[name]) and isinstance(value, Mapping):
            check_values(hints[name], value, where)
        else:
            _check_range(_coerce(value, hints[name], where), fields[name].metadata, where)


def _check_path(cls: type, path: list[str], source: str) -> None:
    """Name the nearest valid key for an unknown dotted override key."""
    current: Any = cls
    for i, part in enumerate(path):
        if not dataclasses.is_dataclass(current):
            raise ConfigError(f"{source}: '{'.'.join(path[:i])}' has no sub-keys")
        names = [f.name for f in dataclasses.fields(current)]
        if part not in names:
            raise ConfigError(f"{source}: unknown key '{'.'.join(path[: i + 1])}'"
                              f"{_suggest(part, names, current, ''.join(p + '.' for p in path[:i]))}")
        current = _type_hints(current)[part]


def _deep_update(base: Mapping[str, Any], new: Mapping[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for k, v in new.items():
        if isinstance(v, Mapping) and isinstance(out.get(k), Mapping):
            out[k] = _deep_update(out[k], v)
        else:
            out[k] = v
    return out


def dump_yaml(obj: Any) -> str:
    """The resolved config as YAML text."""
    return yaml.dump(to_dict(obj), Dumper=_Dumper, sort_keys=False)


def first_difference(a: object, b: object, where: str = "") -> tuple[str, object, object] | None:
    """(dotted key, a's value, b's value) of the first place two config dicts differ, or None."""
    if isinstance(a, dict) and isinstance(b, dict):
        for key in list(a) + [k for k in b if k not in a]:
            found = first_difference(a.get(key), b.get(key), f"{where}{key}.")
            if found:
                return found
        return None
    return None if a == b else (where.rstrip("."), a, b)
