"""Checkpoint files: written atomically, read with torch.load(weights_only=True) only.

A checkpoint is a dict of plain values and tensors (never pickled objects):
    format, version        identify the file
    train_config           TrainConfig as a plain dict (task config inside)
    obs_spec               ObsSpec.to_dict() of the environment it was trained in
    state_dim              global state length (MAPPO critic input)
    actor, critic          state_dicts
    anchor_actor           the frozen init_from actor of an anchored run (ppo.anchor_coef > 0)
    demonstrations         DAgger runs: {"total": pairs ever added}; the pairs are files in RUN/demonstrations/
                           (demonstration_files.py)
    optimizer              Adam state_dict (absent in weights-only exports)
    value_norm, discount   MAPPO running stats, discount logit + its optimiser
    counters               update, world_steps, agent_steps, episodes, best_success ...
    rng                    {"sampler": the run's sampling generator, "torch": torch's global RNG}, both
                           CPU states (uint8 tensors); training draws from no numpy global RNG, and
                           the envs are seeded afresh from (seed, update) on resume (rollout.env_seed)
    pending_row            the metrics row of an update not yet in metrics.jsonl ({} when none)
    layout_sha256          {absolute path: sha256} of the layout files the run names (resume checks them)
    code_sha256            {absolute path: sha256} of its reward-term and evader-model files
    trained_by             which code trained the run: a list of {"from_update", and pursuit_mj.provenance's
                           "version", "git_commit", "git_dirty", "source_sha256", "drone_model_sha256"},
                           one entry per session whose code differed from the entry before (kept by exports)
    init_from_sha256       sha256 of the init_from file as the run began (absent without init_from; kept by exports)
    exported_from          in a policy-only export (export_actor): the checkpoint it came from
"""

from __future__ import annotations

import io
import pickle
import zipfile
import zlib
from pathlib import Path
from typing import Any

import torch

from pursuit_mj.io_utils import CannotWrite, atomic_path
from pursuit_mj.obs_spec import ObsSpec

FORMAT = "pursuit-mj-checkpoint"
VERSION = 1
REQUIRED = ("format", "version", "train_config", "obs_spec", "actor", "counters")
DICTS = ("train_config", "obs_spec", "actor", "counters", "critic", "optimizer", "rng", "value_norm", "discount",
         "pending_row", "anchor_actor", "demonstrations")
#: what zipfile raises for an archive whose directory or headers are damaged: besides BadZipFile, a damaged
#: byte can ask for a zip version, compression method or encryption it lacks (NotImplementedError,
#: RuntimeError) or make a stored entry read as deflated (zlib.error)
ZIP_DAMAGE = (zipfile.BadZipFile, OSError, EOFError, ValueError, RuntimeError, zlib.error)
CONFIG_SECTIONS = ("task", "ppo", "imitation", "residual", "net", "run")  # dicts inside train_config


def save_checkpoint(path: str | Path, payload: dict[str, Any]) -> Path:
    """Write `payload` (plus format/version) to `path` atomically; returns the path."""
    data = {"format": FORMAT, "version": VERSION, **payload}
    # serialised in memory first: torch reports a failed write to a file (a full disk) as a bare
    # RuntimeError, where Python's own write raises the OSError that says why
    buffer = io.BytesIO()
    torch.save(data, buffer)
    try:
        with atomic_path(path) as tmp:
            with open(tmp, "wb") as f:
                f.write(buffer.getbuffer())
    except OSError as exc:  # a full disk, a folder made read-only or removed during the run
        where = f": {exc.filename}" if exc.filename and str(exc.filename) != str(path) else ""
        raise ValueError(f"checkpoint {path}: cannot write it ({exc.strerror or exc}{where})") from None
    except CannotWrite as exc:  # its temporary file could not be made
        raise ValueError(f"checkpoint {exc}") from None
    return Path(path)


def load_checkpoint(path: str | Path) -> dict[str, Any]:
    """Read a checkpoint; a missing, truncated, foreign or tampered file is a ValueError naming it."""
    path = Path(path)
    if path.is_dir():
        hint = next((f"; did you mean {path / n}?" for n in ("best.pt", "last.pt") if (path / n).is_file()), "")
        raise ValueError(f"checkpoint {path}: a folder, not a checkpoint file{hint}")
    if not path.is_file():
        raise ValueError(f"checkpoint {path}: file not found")
    try:
        is_zip = zipfile.is_zipfile(path)
        if is_zip:
            with zipfile.ZipFile(path) as archive:
                damaged = archive.testzip()  # torch.load does not check the archive's CRC-32 sums
    except ZIP_DAMAGE as exc:  # a damaged directory reads as a zip feature zipfile lacks (encryption ...)
        raise ValueError(f"checkpoint {path}: corrupted (its zip archive cannot be read: {type(exc).__name__})") from None
    if not is_zip:
        raise ValueError(f"checkpoint {path}: not a pursuit-mj checkpoint (not a torch zip archive: "
                         f"another kind of file, or one cut short)")
    if damaged is not None:
        raise ValueError(f"checkpoint {path}: corrupted (entry {damaged} fails its checksum)")
    try:
        data = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as exc:
        if "unsupported global" in str(exc).lower():  # torch's safe unpickler met a class or function
            raise ValueError(f"checkpoint {path}: refused: it holds Python objects other than tensors and plain "
                             f"data, and checkpoints are read without running stored code") from None
        raise ValueError(f"checkpoint {path}: corrupted (its data does not unpickle)") from None
    except (RuntimeError, zipfile.BadZipFile, EOFError, OSError, ValueError, KeyError) as exc:
        raise ValueError(f"checkpoint {path}: corrupted (torch could not read it: {type(exc).__name__})") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise ValueError(f"checkpoint {path}: not a pursuit-mj checkpoint")
    if data.get("version") != VERSION:
        raise ValueError(f"checkpoint {path}: format version {data.get('version')}, this code reads {VERSION}")
    missing = [k for k in REQUIRED if k not in data]
    if missing:
        raise ValueError(f"checkpoint {path}: missing entries {missing}")
    for key in DICTS:
        if key in data and not isinstance(data[key], dict):
            raise ValueError(f"checkpoint {path}: entry {key} is a {type(data[key]).__name__}, not a dict (damaged, or "
                             f"not written by pursuit-mj)")
    lacking = [k for k in ("n_pursuers", "n_evaders", "n_rays", "groups") if k not in data["obs_spec"]]
    if lacking:
        raise ValueError(f"checkpoint {path}: its obs_spec lacks {lacking}")
    trained_by = data.get("trained_by", [])
    if not isinstance(trained_by, list) or not all(isinstance(e, dict) for e in trained_by):
        raise ValueError(f"checkpoint {path}: entry trained_by is not a list of dicts (damaged, or not written by pursuit-mj)")
    if not isinstance(data.get("init_from_sha256", ""), str):
        raise ValueError(f"checkpoint {path}: entry init_from_sha256 is not text (damaged, or not written by pursuit-mj)")
    damage = _spec_damage(data["obs_spec"]) or next(
        (f"train_config entry {k} is a {type(v).__name__}, not a dict" for k, v in data["train_config"].items()
         if k in CONFIG_SECTIONS and not isinstance(v, dict)), None)
    if damage:
        raise ValueError(f"checkpoint {path}: {damage} (damaged, or not written by pursuit-mj)")
    for net in ("actor", "critic"):
        for name, value in data.get(net, {}).items():
            if not torch.is_tensor(value):
                raise ValueError(f"checkpoint {path}: entry {net} holds values other than tensors (damaged, or not "
                                 f"written by pursuit-mj)")
            if value.is_floating_point() and not torch.isfinite(value).all():
                raise ValueError(f"checkpoint {path}: non-finite weights (NaN or inf) in {net}.{name}")
    return data


def _spec_damage(spec: dict) -> str | None:
    """What makes a stored obs_spec (ObsSpec.to_dict) unreadable, or None."""
    for key in ("n_pursuers", "n_evaders", "n_rays"):
        value = spec[key]
        if isinstance(value, bool) or not isinstance(value, int) or value < 0:
            return f"obs_spec entry {key} is {value!r}, not a whole number"
    groups = spec["groups"]
    if not isinstance(groups, (list, tuple)) or not all(
            isinstance(g, (list, tuple)) and len(g) == 3 and isinstance(g[0], str) and isinstance(g[1], int)
            and isinstance(g[2], (list, tuple)) for g in groups):
        return "obs_spec entry groups is not a list of [name, width, features]"
    return None


def load_error(exc: Exception) -> str:
    """The telling line of a failed load_state_dict (torch's first line only says that it failed)."""
    lines = [line.strip() for line in str(exc).splitlines() if line.strip()]
    if len(lines) > 1 and lines[0].startswith("Error(s) in loading"):
        return lines[1] + (f" (and {len(lines) - 2} more)" if len(lines) > 2 else "")
    return lines[0] if lines else type(exc).__name__


def is_training_checkpoint(data: dict[str, Any]) -> bool:
    """Whether a loaded checkpoint can resume training (a policy-only export cannot)."""
    return all(k in data for k in ("critic", "optimizer", "rng"))


def _refuse_a_net_no_load_builds(data: dict[str, Any], where: str) -> None:
    """ValueError naming `where` when the checkpoint's `net` settings are ones that loading it
    refuses (train.policy.actor_from_checkpoint reads them so): a net.kind this code has no
    network for, named with the known ones (networks.trunk_class), or another bad net key."""
    from pursuit_mj.configio import build
    from train.config import NetConfig
    from train.networks import trunk_class

    net = data["train_config"].get("net", {})
    try:
        if isinstance(net, dict) and isinstance(net.get("kind"), str):
            trunk_class(net["kind"])
        build(NetConfig, net, "its train_config.net")
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}; no policy could be loaded from the export") from None


def export_actor(src: str | Path, dst: str | Path) -> Path:
    """A small copy of a checkpoint for running the policy only: actor, config, spec, counters.

    No critic, optimiser or random states, so it cannot be resumed; `load_policy` reads it.
    """
    src, dst = Path(src), Path(dst)
    data = load_checkpoint(src)
    _refuse_a_net_no_load_builds(data, f"--export {src} {dst}")
    if dst.exists() and dst.resolve() == src.resolve():
        raise ValueError(f"--export {src} {dst}: OUT is the checkpoint itself; write the export to another file")
    if dst.is_file():
        try:
            replaced = load_checkpoint(dst)
        except ValueError:
            raise ValueError(f"--export {src} {dst}: OUT exists and is not a policy export (a log, a config, another "
                             f"file of yours), which the export would replace; choose another file") from None
        if is_training_checkpoint(replaced):
            raise ValueError(f"--export {src} {dst}: OUT is a training checkpoint, which the export would replace "
                             f"(losing its critic and optimiser state); choose another file")
    keep = {k: data[k] for k in ("train_config", "obs_spec", "state_dim", "actor", "counters", "trained_by", "init_from_sha256")
            if k in data}
    keep["exported_from"] = str(data.get("exported_from", src))
    return save_checkpoint(dst, keep)


def check_obs_spec(data: dict[str, Any], spec: ObsSpec, path: str | Path) -> None:
    """Refuse a checkpoint whose observation features differ from the environment's."""
    why = spec.compatible(data["obs_spec"])
    if why is not None:
        raise ValueError(f"checkpoint {path}: observation spec does not match the environment: {why}")
