"""What a run checks before it starts from a checkpoint or resumes one, and the provenance it records.

A resumed run must train in the arena and with the code (reward terms, evader model) it began
with; a run started from another's checkpoint (init_from) must build the same actor; every
checkpoint says which code trained it (trained_by) and what it started from (init_from_sha256).
The Trainer (train/trainer.py) calls these; `pursuit-mj train --resume` uses best_instead too.
"""

from __future__ import annotations

import os
from pathlib import Path

from pursuit_mj.configio import build
from pursuit_mj.io_utils import file_sha256
from pursuit_mj.provenance import provenance

from .checkpoint import is_training_checkpoint, load_checkpoint
from .config import NetConfig, TrainConfig
from .networks import TRUNKS


def train_diverged_hint(last: Path | None, update: int, key: str) -> str:
    """What a diverged run's folder keeps and how `pursuit-mj train` starts again from it with the
    setting `key` changed: the checkpoint `last` of update `update`, or None when none was saved."""
    if last is None:
        return "no update was saved"
    return f"{last} keeps update {update}, from which a new run can start (--init-from {last} --set {key}=...)"


def init_from_sha256(cfg: TrainConfig, checkpoint: dict | None) -> str | None:
    """sha256 of the init_from file as the run began (the checkpoint entry init_from_sha256): a
    resumed run's stored one (the file may have changed or gone since), else the file's now;
    None without init_from, or for a run resumed from a checkpoint written before it was kept."""
    if checkpoint is not None:
        return checkpoint.get("init_from_sha256")
    return file_sha256(cfg.init_from) if cfg.init_from and Path(cfg.init_from).is_file() else None


def trained_by(checkpoint: dict | None, start_update: int) -> list[dict]:
    """The checkpoint entry trained_by (train/checkpoint.py) for a session starting at
    `start_update`: a resumed run's list (`checkpoint`, None for a new run), with this code's
    provenance appended when it differs from the last entry's (a run resumed by other code)."""
    entries = [dict(e) for e in (checkpoint or {}).get("trained_by", [])]
    now = provenance()
    if not entries or {k: v for k, v in entries[-1].items() if k != "from_update"} != now:
        entries.append({"from_update": int(start_update), **now})
    return entries


ACTOR_SHAPE_KEYS = ("kind", "encoder_width", "hidden", "use_rays")  # the net.* keys that decide the actor's weights


def check_same_network(data: dict, net: NetConfig, path: str | Path) -> None:
    """ValueError naming both networks unless the checkpoint `data`'s actor was built with this
    run's net.kind, widths and use_rays (ACTOR_SHAPE_KEYS, or those of them its kind's trunk uses:
    its SHAPE_KEYS in train/networks.py, and the kind always): its weights would not load, or, for two
    kinds with the same weight names, would load into another network. A kind this code does not
    know is refused by name (train_config.net: key 'kind')."""
    stored = build(NetConfig, data["train_config"].get("net", {}), f"init_from {path}: train_config.net")
    keys = getattr(TRUNKS.get(stored.kind), "SHAPE_KEYS", ACTOR_SHAPE_KEYS)  # those the stored network's weights depend on
    keys = ("kind", *(k for k in keys if k != "kind"))  # another kind is another network, whatever its SHAPE_KEYS say
    differ = [k for k in keys if getattr(stored, k) != getattr(net, k)]
    if differ:
        def shown(cfg: NetConfig) -> str:
            return ", ".join(f"net.{k} {_text(getattr(cfg, k))}" for k in differ)

        sets = " ".join(f"--set net.{k}={_text(getattr(stored, k), yaml=True)}" for k in differ)
        raise ValueError(f"init_from {path}: its actor is {shown(stored)}; this run builds {shown(net)} "
                         f"(to start from it, give the run the same network: {sets})")


def _text(value, yaml: bool = False) -> str:
    """A net.* value as the error shows it (tuples as lists; booleans as YAML writes them)."""
    if isinstance(value, tuple):
        return f"[{', '.join(map(str, value))}]" if not yaml else f"[{','.join(map(str, value))}]"
    if isinstance(value, bool):
        return str(value).lower()
    return str(value)


def check_layout_files(cfg: TrainConfig, trained: dict, run_dir: str | Path, restart: str) -> None:
    """Refuse to resume a run whose layout files cannot be loaded from here or differ from the
    ones it trained on (sha256 in `trained`, by path; runs saved before it was kept are not checked);
    `restart` says how to start the run again instead."""
    try:
        cfg.check_layouts(f"--resume {run_dir}: the run's stored config")
    except ValueError as exc:
        relative = [path for _, path in cfg.layout_files() if not os.path.isabs(path)]
        hint = (f"; the run stored {relative[0]} relative to the folder it started in: resume from that folder"
                if relative else "")
        raise ValueError(f"{exc}{hint}") from None
    for key, path in cfg.layout_files():
        if path in trained and file_sha256(path) != trained[path]:
            raise ValueError(f"--resume {run_dir}: layout file {path} ({key}) has changed since the run started: "
                             f"the rest of the run would train and validate in another arena than the first part. "
                             f"Restore the file, or {restart}")


def check_code_files(cfg: TrainConfig, trained: dict, run_dir: str | Path, restart: str) -> None:
    """Refuse to resume a run whose code files (reward terms, evader model) cannot be loaded or
    differ from the ones it trained with (sha256 in `trained`, by path); `restart` as check_layout_files."""
    cfg.check_code(f"--resume {run_dir}: the run's stored config")
    for key, path in cfg.code_files():
        if path in trained and file_sha256(path) != trained[path]:
            what = "other rewards" if key == "rewards" else "other evaders"
            raise ValueError(f"--resume {run_dir}: {path} ({key}) has changed since the run started: the rest of the "
                             f"run would learn from {what} than the first part. Restore the file, or {restart}")


def checkpoint_every_of(config_yaml: Path) -> int:
    """run.checkpoint_every of the run whose config.yaml this is (1 if it cannot be read)."""
    from pursuit_mj.configio import load_yaml

    try:
        every = load_yaml(config_yaml)["run"]["checkpoint_every"]
    except Exception:  # noqa: BLE001 - missing, damaged or hand-edited: the new run's own setting decides
        return 1
    return every if isinstance(every, int) and not isinstance(every, bool) and every >= 1 else 1


def best_instead(run_dir: Path) -> str:
    """How to go on from the run's best.pt when its last.pt is unusable ('' if best.pt is unusable too)."""
    try:
        best = load_checkpoint(run_dir / "best.pt")
    except ValueError:
        return ""
    if not is_training_checkpoint(best):
        return ""
    return (f"; its best.pt (update {best['counters'].get('update')}) is intact: copy it over last.pt to resume from "
            f"there (the updates after it are trained again)")
