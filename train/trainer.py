"""The training loop: collect, learn, log, validate, checkpoint; resumable and interrupt-safe.

Run folder (<runs_dir>/<name>/):
    last.pt        after every `checkpoint_every` updates (default every update), atomically
    best.pt        the checkpoint with the best validation success so far
    metrics.jsonl  one row per update: counters, throughput, reward terms, losses, validation
    config.yaml    the resolved TrainConfig
    demonstrations/  DAgger only: the dataset's pairs, written before each last.pt (demonstration_files.py)
A kill -9 at any moment therefore loses at most the update in flight. Ctrl-C stops at once
and keeps the last consistent state: `Trainer.resume(run_dir)` continues with the same
counters, optimiser state and sampling streams (torch's); the environments start afresh,
seeded from the run's seed and the update they start at (rollout.env_seed), since a world's
state in mid-episode is not stored. An update's metrics row stays in last.pt until it is in
metrics.jsonl, so an interrupted run neither loses nor repeats a row.
"""

from __future__ import annotations

import collections
import contextlib
import copy
import dataclasses
import json
import shutil
import time
from pathlib import Path
from typing import IO, Callable

import numpy as np
import torch

from pursuit_mj.config import LEARNED_TASK_KEYS, task_differences
from pursuit_mj.configio import dump_yaml, to_dict
from pursuit_mj.evaluation import capture_steps
from pursuit_mj.io_utils import (atomic_write_text, check_writable_folder, file_sha256, interrupt_handled, made_here,
                                 no_new_empty_folders, remove_leftover_parts)
from pursuit_mj.policies import make_policy
from pursuit_mj.sensing import privileged_config

from .agent import ActorCritic
from .checkpoint import check_obs_spec, is_training_checkpoint, load_checkpoint, load_error, save_checkpoint
from .child_process import WorkerExited
from .config import TrainConfig, defaults_filled_in, train_config_from_dict, usable_cores
from .critic_worker import CriticWorker
from .demonstration_files import FOLDER as DEMONSTRATIONS, DemonstrationFiles
from .discount import Discount
from .folder_lock import FolderInUse, lock_run_folder, release_lock
from .imitation import DaggerCollector, Demonstrations, imitation_update, teacher_share
from .metrics_log import MetricsLog, json_ready, missing_updates
from .networks import registered_from_outside, team_mismatch
from pursuit_mj.recording.rerun_scalars import RerunScalarLogger
from .policy import ActorPolicy, trained_team
from .progress_bar import advance_bar, progress_bar
from .ppo import advantages_and_returns, ppo_update, teacher_labels_needed, teacher_weight
from .rollout import Collector, RolloutStats, hand_made_team, make_action_path, make_collector, make_training_env
from .rollout_worker import RolloutWorker
from .run_checks import (best_instead, check_code_files, check_layout_files, check_same_network, checkpoint_every_of,
                         init_from_sha256, train_diverged_hint, trained_by)
from .storage import Rollout
from .validation import FixedSeedValidator, summarise, versus

WINDOW = 100  # episodes in the progress bar's moving success / collision / steps


@dataclasses.dataclass
class Counters:
    """Progress of a run; saved in every checkpoint and restored by resume."""

    update: int = 0
    world_steps: int = 0
    agent_steps: int = 0
    episodes: int = 0
    best_success: float = -1.0
    best_steps: float = float("inf")  # its mean capture steps (a failed episode counts as max_steps)
    best_update: int = -1
    seconds: float = 0.0  # wall time of the run so far: collection, updates and validations
    validation_seconds: float = 0.0  # the part of `seconds` spent in validations


# what a new run refused in a folder holding an earlier run whose last.pt is gone tells the user (Trainer)
EARLIER_RUN_ADVICE = "Go on from its best.pt (copy it over last.pt, then --resume), or train under another --name"


class Trainer:
    """One training run: env, networks, optimiser, counters; `train()` runs it to the end.

    `checkpoint` (a loaded last.pt) restores a run; otherwise `cfg.init_from` may seed the
    weights. `log` receives one-line messages (resume, init, interrupt).
    """

    def __init__(self, cfg: TrainConfig, checkpoint: dict | None = None, log: Callable[[str], None] = print,
                 held_lock: IO | None = None, earlier_run_advice: str | None = None):
        """`held_lock`: the run folder's lock, already taken by the caller (`resume` takes it before it
        reads last.pt); the trainer releases it when it ends. One that cannot start leaves it to the
        caller, who knows whether its lock file was there before (`release_lock`).
        `earlier_run_advice`: what a new run refused in a folder holding an earlier run without its
        last.pt tells the user to do instead (default: train's; a study, whose flags are others, says its own)."""
        self._earlier_run_advice = earlier_run_advice or EARLIER_RUN_ADVICE
        self._start(cfg, checkpoint, log, held_lock)

    def _start(self, cfg: TrainConfig, checkpoint: dict | None, log: Callable[[str], None], held_lock: IO | None) -> None:
        cfg.check_complete()
        cfg.check_layouts()  # before the run folder is made: a bad one named with its key, not from deep in the env
        cfg.check_code()
        if checkpoint is None:
            cfg = cfg.with_absolute_files()  # so that the stored config loads them from any folder
        self._layout_sha256 = {path: file_sha256(path) for _, path in cfg.layout_files()}  # kept: a resume checks them
        self._code_sha256 = {path: file_sha256(path) for _, path in cfg.code_files()}
        self._init_from_sha256 = init_from_sha256(cfg, checkpoint)
        self.cfg = cfg
        self.log = log
        for line in cfg.idle_settings():
            log(f"[train] note: {line}")
        self.run_dir = cfg.run_dir
        self.resume_command = f"pursuit-mj train --resume {self.run_dir}"  # what an interrupted run tells the user
        # what a diverged run tells the user (a study, whose flags are others, says its own)
        self.diverged_hint: Callable[[Path | None, int, str], str] = train_diverged_hint
        with no_new_empty_folders():  # a run refused here leaves no folder of run.runs_dir=a/b made for it
            self._take_run_folder(checkpoint, log, held_lock)

    def _take_run_folder(self, checkpoint: dict | None, log: Callable[[str], None], held_lock: IO | None) -> None:
        """Make and lock the run folder, then build the run (_build). A run that cannot start
        leaves the folder free, removes it if it made it (a later --resume would take it for a
        run), and in a folder that was there removes the lock file it made (a `held_lock` it leaves
        to its caller)."""
        cfg = self.cfg
        check_writable_folder(self.run_dir, f"run folder (run.runs_dir {cfg.run.runs_dir}, name {cfg.name})")
        made_folder = made_here(self.run_dir)  # not one that was there (run.runs_dir=new/../keep), nor another's
        new_lock = held_lock is None and not (self.run_dir / ".lock").exists()  # the folder there: new/../keep/.lock found
        try:
            # before anything in the folder is read or written
            self._lock = held_lock if held_lock is not None else lock_run_folder(self.run_dir)
        except FolderInUse:  # another trainer made it meanwhile, perhaps: it is that one's
            raise
        except ValueError:  # it could not be written: remove what this run made
            if made_folder:
                shutil.rmtree(self.run_dir, ignore_errors=True)
            raise
        # what a run that fails in its first update removes (_remove_a_run_that_holds_nothing): not what was there
        self._made_folder, self._new_lock = made_folder, new_lock
        self._found = {name for name in RUN_FILES if (self.run_dir / name).exists()}
        try:
            left = remove_leftover_parts(self.run_dir)  # of saves a kill -9 cut short: no other process writes here
            if left:
                log(f"[train] removed {len(left)} temporary file{'s' if len(left) > 1 else ''} of a save cut short "
                    f"in {self.run_dir}: {', '.join(p.name for p in left)}")
            if checkpoint is None:
                self._refuse_an_earlier_run()
            self._build(checkpoint)
        except BaseException:  # a run that cannot start leaves the folder free, and no lock file of its own there
            if held_lock is None:
                release_lock(self._lock, self.run_dir / ".lock", remove_file=new_lock)
            if made_folder:
                shutil.rmtree(self.run_dir, ignore_errors=True)
            raise

    def _build(self, checkpoint: dict | None) -> None:
        """Everything else of __init__: env, networks, optimiser, restored state, collectors, logs."""
        cfg = self.cfg
        torch.manual_seed(cfg.seed)
        self.counters = Counters()
        self.generator = torch.Generator().manual_seed(cfg.seed)
        restored = read_counters(checkpoint, self.run_dir / "last.pt") if checkpoint else None
        start_update = restored.update if restored else 0
        self._trained_by = trained_by(checkpoint, start_update)
        self.env = make_training_env(cfg, start_update)
        self.spec = self.env.obs_spec
        self.model = ActorCritic(self.spec, self.env.state_dim, cfg)
        self.optimizer = torch.optim.Adam(self.model.parameters(), lr=self._base_lr(), eps=1e-5, fused=True)
        p = cfg.ppo
        self.discount = Discount(p.gamma, p.learnable_gamma, p.gamma_meta_lr, p.gamma_outer)
        self.anchor: torch.nn.Module | None = None  # the frozen start of an anchored run (ppo.anchor_coef)
        if checkpoint is not None:
            self._restore(checkpoint, restored)
        elif cfg.init_from:
            self._init_from(cfg.init_from)
        self.buffer = Rollout(cfg.rollout_steps(), cfg.n_envs, self.env.n_pursuers, self.env.obs_dim,
                              self.env.state_dim if cfg.algo == "mappo" else 0)
        self.demos: Demonstrations | None = None
        self.overlap = cfg.run.overlap and cfg.algo != "dagger"
        self._heuristic_records: list | None = None  # the heuristic team's validation episodes (validation_vs_heuristic)
        cores = usable_cores()
        # the critic's half of each update in a child process: only where a core would idle otherwise
        self.split_update = cfg.run.split_update and not self.overlap and cores >= 2
        self.update_threads = cfg.run.update_threads(self.overlap, cores, self.split_update)
        spawns = " and ".join(k for k, on in (("run.split_update", self.split_update), ("run.overlap", self.overlap)) if on)
        why = registered_from_outside(cfg.net.kind, spawns) if spawns else None
        if why is not None:
            raise ValueError(why)
        self.critic_worker: CriticWorker | None = None  # started with the first rollout (split_update)
        self.collector: Collector | DaggerCollector | None = None  # in-process collection (overlap off)
        self.worker: RolloutWorker | None = None  # collection in a child process (overlap on), started on first use
        if cfg.algo == "dagger":
            teacher_task = privileged_config(cfg.task, cfg.imitation.teacher_sees)
            if teacher_task is cfg.task:
                teacher = hand_made_team(cfg.imitation.teacher, cfg, self.env, "imitation.teacher")
            else:
                teacher = make_policy(cfg.imitation.teacher, teacher_task, seed=cfg.seed, source="imitation.teacher")
            self.demos = Demonstrations(cfg.imitation.dataset_size, self.env.obs_dim)
            if checkpoint is not None:
                self._restore_demonstrations(checkpoint)
            self.collector = DaggerCollector(self.env, self.model, teacher, self.demos, self.generator, make_action_path(cfg, self.env),
                                             teacher_task=None if teacher_task is cfg.task else teacher_task)
        elif not self.overlap:
            self.collector = make_collector(cfg, self.env, self.model, self.generator)
        self.metrics = MetricsLog(self.run_dir / "metrics.jsonl")
        # the timeline is named for what it counts (the logger's default, env_steps, said nothing of which steps)
        self.rerun = (RerunScalarLogger(self.run_dir / "metrics.rrd", run_name=cfg.name, timeline="world_steps")
                      if cfg.run.rerun else None)
        if self.rerun is not None and checkpoint:  # the file starts afresh: the curves so far come from the log
            for row in self.metrics.rows():
                self.rerun.log(int(row["world_steps"]), row)
        self.recent = collections.deque(maxlen=WINDOW)
        self._validator = self._make_validator()
        self._saved_update = self.counters.update if checkpoint else -1
        self._pending_row: dict = dict(checkpoint.get("pending_row") or {}) if checkpoint else {}
        self._consistent = True

    # ------------------------------------------------------------------ construction

    @classmethod
    def resume(cls, run_dir: str | Path, total_steps: int | None = None, log: Callable[[str], None] = print,
               max_minutes: float | None = None, progress: bool | None = None,
               check: Callable[[TrainConfig], None] | None = None, rerun: bool | None = None,
               restart: str | None = None) -> "Trainer":
        """Continue the run in `run_dir` from last.pt with its own config; only the length of the
        run (total_steps, max_minutes), the progress bar and rerun streaming may change. `check(stored config)`
        runs before anything is restored (to refuse a resume asked with other settings). `restart`: how
        the refusal of a run whose layout or code files changed says to start the run again, where not
        as `pursuit-mj train` does ('start a new run from this one with --init-from RUN/last.pt')."""
        run_dir = Path(run_dir).resolve()  # `--resume .` from inside the folder: its name, not ''
        # held before last.pt is read: a trainer of this folder ending meanwhile cannot leave it one save behind.
        # Only a folder with a last.pt: one without has nothing to resume and gets no lock file of ours
        # (a mistyped name makes no folder, a folder that holds no run no '.lock')
        new_lock = not (run_dir / ".lock").exists()  # a folder copied without it: a refused resume leaves none there
        lock = lock_run_folder(run_dir) if (run_dir / "last.pt").is_file() else None
        try:
            return cls._resume_holding(run_dir, lock, total_steps, log, max_minutes, progress, check, rerun, restart)
        except BaseException:
            if lock is not None and not lock.closed:
                release_lock(lock, run_dir / ".lock", remove_file=new_lock)
            raise

    @classmethod
    def _resume_holding(cls, run_dir: Path, lock: IO | None, total_steps: int | None, log: Callable[[str], None],
                        max_minutes: float | None, progress: bool | None,
                        check: Callable[[TrainConfig], None] | None, rerun: bool | None,
                        restart: str | None = None) -> "Trainer":
        """resume's work once it holds the run folder's lock (None where the folder does not exist)."""
        path = run_dir / "last.pt"
        try:
            data = load_checkpoint(path)
        except ValueError as exc:
            raise ValueError(f"{exc}{best_instead(Path(run_dir))}") from None
        if not is_training_checkpoint(data) and "exported_from" not in data:
            lacking = [k for k in ("critic", "optimizer", "rng") if k not in data]
            raise ValueError(f"--resume {run_dir}: {path} lacks {lacking}, which a resume needs (damaged, or written "
                             f"by other code)")
        if not is_training_checkpoint(data):
            raise ValueError(f"--resume {run_dir}: {path} is a policy-only export (of {data.get('exported_from', 'a run')}), "
                             f"not a training checkpoint: it holds no critic, optimiser or random state to resume from")
        cfg = train_config_from_dict(data["train_config"], f"checkpoint {path}: train_config")
        if check is not None:
            check(cfg)
        restart = restart or f"start a new run from this one with --init-from {Path(run_dir) / 'last.pt'}"
        check_layout_files(cfg, data.get("layout_sha256", {}), run_dir, restart)
        check_code_files(cfg, data.get("code_sha256", {}), run_dir, restart)
        filled = defaults_filled_in(data["train_config"], cfg)
        if filled:
            shown = ", ".join(filled[:6]) + (f" and {len(filled) - 6} more" if len(filled) > 6 else "")
            log(f"note: {path} was written before these settings existed, and resumes with today's defaults for them: {shown}")
        run = dataclasses.replace(cfg.run, runs_dir=str(Path(run_dir).parent))
        if progress is not None:
            run = dataclasses.replace(run, progress=progress)
        if rerun is not None:
            run = dataclasses.replace(run, rerun=rerun)
        cfg = dataclasses.replace(cfg, run=run, name=Path(run_dir).name)  # run_dir resolved above: '.' has no name
        if total_steps is not None:
            cfg = dataclasses.replace(cfg, total_steps=total_steps)
        if max_minutes is not None:
            cfg = dataclasses.replace(cfg, max_minutes=max_minutes)
        return cls(cfg, checkpoint=data, log=log, held_lock=lock)

    def _restore(self, data: dict, counters: Counters) -> None:
        path = self.run_dir / "last.pt"
        check_obs_spec(data, self.spec, path)
        part = "actor weights"
        try:  # a damaged or hand-edited file, or one whose train_config no longer builds the network it holds
            self.model.actor.load_state_dict(data["actor"])
            part = "critic weights"
            self.model.critic.load_state_dict(data["critic"])
            part = "optimiser state"
            self.optimizer.load_state_dict(data["optimizer"])
            if any(torch.is_tensor(v) and k != "step" and v.shape != p.shape for p, s in self.optimizer.state.items() for k, v in s.items()):
                raise ValueError("its moments do not match the parameters' shapes")
            part = "value normalisation"
            if self.model.value_norm is not None and data.get("value_norm"):
                self.model.value_norm.load_state_dict(data["value_norm"])
            elif self.model.value_norm is not None:
                self.log(f"note: {path} holds no value statistics (an older or edited file): MAPPO's value normalisation "
                         f"starts afresh, so its critic's first values are off until they settle")
            part = "discount state"
            if "discount" in data:
                self.discount.load_state_dict(data["discount"])
            if self._anchored:
                part = "anchor actor"
                self.anchor = self._frozen_actor()
                self.anchor.load_state_dict(data["anchor_actor"])
            part = "random state (rng)"
            sampler, global_rng = data["rng"]["sampler"], data["rng"]["torch"]
            self.generator.set_state(sampler)
            torch.set_rng_state(global_rng)
        except (RuntimeError, KeyError, TypeError, ValueError, AttributeError) as exc:
            raise ValueError(f"checkpoint {path}: cannot resume from its {part} ({load_error(exc)}); the file is damaged, or "
                             f"its train_config builds another network than it holds") from None
        self.counters = counters
        self._adopt_newer_best()
        # a row still pending may have reached the log before the run was stopped: it is logged again
        logged = self.counters.update - (1 if data.get("pending_row") else 0)
        metrics = MetricsLog(self.run_dir / "metrics.jsonl")
        later = sorted(r.get("update", 0) for r in metrics.rows() if r.get("update", 0) > logged)
        if later and self._last_is_own_best():  # as best_instead advises for a damaged last.pt
            self.log(f"note: last.pt is this run's best.pt (update {self.counters.update}): the run goes on from it, and the "
                     f"rows of updates {later[0]}-{later[-1]} leave metrics.jsonl and are written again as it goes")
        elif len(later) > self.cfg.run.checkpoint_every + 1:  # more than a crash between checkpoints leaves
            raise ValueError(f"--resume {self.run_dir}: last.pt is at update {logged}, but metrics.jsonl holds the rows of "
                             f"updates {later[0]}-{later[-1]}: it is not this run's latest checkpoint (copied from another "
                             f"run, or an older copy put back), and a resume would cut those rows from the log. Put the "
                             f"run's own last.pt back, or move metrics.jsonl aside to go on from this one")
        metrics.truncate_after(logged)
        missing = missing_updates({r.get("update") for r in metrics.rows()}, logged)
        if missing:  # the file deleted or cut by hand: the curves will have a gap
            first, last, count = missing
            span = f"{first}-{last}" if count > 1 else f"{first}"
            if last - first + 1 != count:
                span += f" ({count} of them)"
            self.log(f"note: {metrics.path} lacks the rows of updates {span} (deleted or cut since they were "
                     f"logged); the log goes on from update {logged + 1}")
        self.log(f"resumed {self.run_dir} at update {self.counters.update} ({self.counters.world_steps} world steps)")

    def _restore_demonstrations(self, data: dict) -> None:
        """DAgger: refill the dataset with the pairs last.pt's update had (demonstration_files.py)."""
        total = (data.get("demonstrations") or {}).get("total")
        if not isinstance(total, int) or isinstance(total, bool) or total < 0:
            self.log("note: last.pt keeps no count of demonstrations (written before they were kept): the dataset "
                     "refills from new rollouts")
            return
        kept = DemonstrationFiles(self.run_dir).restore(self.demos, self.counters.update, total)
        held = min(total, self.demos.capacity)
        if kept < held:
            self.log(f"note: {self.run_dir / DEMONSTRATIONS}: {kept} of the {held} demonstration pairs last.pt had were "
                     f"found (files missing or damaged); the dataset refills from new rollouts")

    def _refuse_an_earlier_run(self) -> None:
        """A new run in a folder whose last.pt is gone but whose log or best.pt reach past the first
        checkpoint of an earlier run is refused: it would cut that log and replace that best.pt.
        (A run killed before its first checkpoint leaves no more than that: it starts afresh.)"""
        if (self.run_dir / "last.pt").exists():
            return
        first = max(self.cfg.run.checkpoint_every, checkpoint_every_of(self.run_dir / "config.yaml"))
        rows = [r.get("update") for r in MetricsLog(self.run_dir / "metrics.jsonl").rows()]
        later = [u for u in rows if isinstance(u, int) and u > first]
        try:
            best = load_checkpoint(self.run_dir / "best.pt")["counters"].get("update", 0)
        except (ValueError, KeyError, TypeError, AttributeError):
            best = 0
        best = best if isinstance(best, int) and best > first else 0
        if later or best:
            held = [f"metrics.jsonl rows up to update {max(later)}" if later else "", f"best.pt of update {best}" if best else ""]
            raise ValueError(f"run folder {self.run_dir} holds an earlier run ({' and '.join(h for h in held if h)}) whose "
                             f"last.pt is gone; a new run would cut its log and replace its best.pt. {self._earlier_run_advice}")

    def _adopt_newer_best(self) -> None:
        """Take the best-validation record from best.pt when it is newer than last.pt's (a crash
        after best.pt was written but before last.pt was): otherwise the resumed run judges its
        validations against an older best and may replace best.pt with a worse policy."""
        c, path = self.counters, self.run_dir / "best.pt"
        try:
            best = read_counters(load_checkpoint(path), path)
        except (ValueError, KeyError) as exc:
            if c.best_update >= 0:  # the record names a policy no longer on disk: forget it, so a new one is written
                why = "it is gone" if not path.exists() else f"it is unusable: {load_error(exc)}"
                self.log(f"note: {path} of update {c.best_update} (validation success {c.best_success:.3f}) is lost ({why}); "
                         f"its record is dropped, and the next validation writes a new one")
                c.best_success, c.best_steps, c.best_update = Counters.best_success, Counters.best_steps, Counters.best_update
            return
        if best.best_update > c.best_update:
            c.best_success, c.best_steps, c.best_update = best.best_success, best.best_steps, best.best_update

    def _last_is_own_best(self) -> bool:
        """Whether last.pt is a byte copy of this run's best.pt (put there to go on from it)."""
        last, best = self.run_dir / "last.pt", self.run_dir / "best.pt"
        try:
            return best.is_file() and best.stat().st_size == last.stat().st_size and best.read_bytes() == last.read_bytes()
        except OSError:
            return False

    def _init_from(self, path: str) -> None:
        """Start from another run's weights (fine_tune): actor always, critic when it fits."""
        if not Path(path).exists():
            hint = (" fine_tune starts from a full_obs run: train one first (pursuit-mj train --config full_obs), "
                    "then pass its best.pt" if self.cfg.regime == "fine_tune" else "")
            raise ValueError(f"init_from {path}: no such checkpoint (set it with --init-from or --set init_from=...)."
                             f"{hint}")
        try:
            data = load_checkpoint(path)
        except ValueError as exc:  # a folder, a damaged file: named with the key it came from
            raise ValueError(f"init_from (--init-from): {exc}") from None
        check_obs_spec(data, self.spec, path)
        check_same_network(data, self.cfg.net, path)
        why = team_mismatch(self.cfg.net.kind, data["obs_spec"], self.spec)
        if why is not None:
            raise ValueError(f"init_from {path}: {why}")
        try:
            self.model.actor.load_state_dict(data["actor"])
        except RuntimeError as exc:
            raise ValueError(f"init_from {path}: actor weights do not fit this network ({load_error(exc)})") from None
        notes = []
        if self._anchored:
            self.anchor = self._frozen_actor()
            notes.append(f"it is also the anchor, kept by KL weight ppo.anchor_coef {self.cfg.ppo.anchor_coef:g}")
        log_std = self.model.actor.log_std.detach()
        if not torch.allclose(log_std, torch.full_like(log_std, self.cfg.net.init_log_std)):
            shown = ", ".join(sorted({f"{x:g}" for x in log_std.tolist()}))
            notes.append(f"its log std {shown} replaces net.init_log_std {self.cfg.net.init_log_std:g} (the exploration "
                         f"noise continues from the checkpoint)")
        src = data["train_config"]
        src_observability = src["task"]["observability"]
        if self.cfg.regime == "fine_tune" and src_observability != "full":
            raise ValueError(f"init_from {path}: fine_tune starts from a full_obs run, and this checkpoint was trained with "
                             f"observability {src_observability}; to continue it under partial observability, use "
                             f"--set regime=custom with the same init_from")
        src_algo = src.get("algo")
        same_critic = (src_algo == "mappo") == (self.cfg.algo == "mappo")  # dagger trains a ppo-style critic
        fresh = ("" if self.cfg.algo == "dagger" else
                 f" ({self.cfg.ppo.critic_warmup} update(s) train it alone, ppo.critic_warmup)" if self.cfg.ppo.critic_warmup
                 else " (ppo.critic_warmup=N would train it alone for N updates before the actor moves)")
        if "critic" not in data:
            notes.append(f"it is a policy-only export: the critic starts fresh{fresh}")
        elif not same_critic:
            notes.append(f"its critic ({src_algo}) is not this run's ({self.cfg.algo}): the critic starts fresh{fresh}")
        else:
            try:
                self.model.critic.load_state_dict(data["critic"])
            except RuntimeError:
                notes.append(f"its critic does not fit (other team size or network): the critic starts fresh{fresh}")
            else:  # a normalised critic's outputs mean nothing without the statistics they were scaled by
                if self.model.value_norm is not None and data.get("value_norm"):
                    self.model.value_norm.load_state_dict(data["value_norm"])
                elif self.model.value_norm is not None:
                    notes.append("it holds no value statistics (an older or edited file): MAPPO's value normalisation "
                                 "starts afresh, so its critic's first values are off until they settle")
        logit = (data.get("discount") or {}).get("logit")
        if (src.get("ppo") or {}).get("learnable_gamma") and torch.is_tensor(logit) and logit.numel() == 1:
            learned = float(torch.sigmoid(logit.float()))
            if abs(learned - self.cfg.ppo.gamma) > 5e-5:
                notes.append(f"its learned discount {learned:.4f} is not carried over: gamma starts at ppo.gamma "
                             f"{self.cfg.ppo.gamma:g}")
        src_base = (src.get("residual") or {}).get("base", "none")
        if src_base != self.cfg.residual.base:
            notes.append(f"its actor was trained as a correction to base team {src_base!r}, here it acts on base "
                         f"{self.cfg.residual.base!r}")
        if bool(src.get("shield", False)) != self.cfg.shield:
            notes.append(f"it was trained {'behind' if src.get('shield') else 'without'} the shield, this run is "
                         f"{'behind' if self.cfg.shield else 'without'} it")
        keys = [k for k in LEARNED_TASK_KEYS if k != "observability"]  # that one the line says anyway
        differ = task_differences(src.get("task") or {}, self.cfg.task, keys)
        if differ:  # legitimate (a point-trained actor continued in quadrotor physics), but worth knowing
            notes.append("its task differs from this run's (checkpoint -> this run): "
                         + ", ".join(f"{k} {then} -> {now}" for k, then, now in differ))
        self.log(f"initialised from {path} (trained with observability {src_observability}, "
                 f"now {self.cfg.task.observability})" + "".join(f"; note: {n}" for n in notes))

    @property
    def _anchored(self) -> bool:
        return self.cfg.algo != "dagger" and self.cfg.ppo.anchor_coef > 0

    def _frozen_actor(self) -> torch.nn.Module:
        """A copy of the actor as it is now, out of the optimiser's reach."""
        return copy.deepcopy(self.model.actor).requires_grad_(False)

    # ------------------------------------------------------------------ checkpoints

    def checkpoint_payload(self) -> dict:
        return {
            "train_config": to_dict(self.cfg),
            "obs_spec": self.spec.to_dict(),
            "state_dim": self.env.state_dim,
            "actor": self.model.actor.state_dict(),
            "critic": self.model.critic.state_dict(),
            "optimizer": self.optimizer.state_dict(),
            "value_norm": self.model.value_norm.state_dict() if self.model.value_norm else {},
            "discount": self.discount.state_dict(),
            **({"anchor_actor": self.anchor.state_dict()} if self.anchor is not None else {}),
            # DAgger: how many pairs were ever added; the pairs are in RUN/demonstrations (demonstration_files.py)
            **({"demonstrations": {"total": self.demos.total}} if self.demos is not None else {}),
            "counters": dataclasses.asdict(self.counters),
            "rng": {"sampler": self.generator.get_state(), "torch": torch.get_rng_state()},
            # the log row of an update whose validation Ctrl-C cut short (plain JSON values): a resume
            # validates it and writes the row, so no update goes unlogged or unvalidated
            "pending_row": json.loads(json.dumps(json_ready(self._pending_row))) if self._pending_row else {},
            "layout_sha256": self._layout_sha256,
            "code_sha256": self._code_sha256,
            "trained_by": self._trained_by,
            **({"init_from_sha256": self._init_from_sha256} if self._init_from_sha256 else {}),
        }

    def save(self, name: str = "last.pt") -> Path:
        try:
            demo_files = DemonstrationFiles(self.run_dir) if name == "last.pt" and self.demos is not None else None
            if demo_files is not None:  # first: last.pt counts the pairs on disk
                demo_files.save(self.demos, self.counters.update)
            path = save_checkpoint(self.run_dir / name, self.checkpoint_payload())
            if demo_files is not None:
                demo_files.prune(self.demos)
        except ValueError as exc:  # a full disk, a folder made read-only: say what is kept and how to go on
            raise self._cannot_write(exc) from None
        if name == "last.pt":
            self._saved_update = self.counters.update
        return path

    # ------------------------------------------------------------------ validation

    def _make_validator(self) -> FixedSeedValidator:
        """The fixed validation episodes, built as the run starts: a validation layout that cannot be
        loaded is refused before any update, naming its key (found at the first validation, it ended
        the run there, and every resume of it)."""
        r = self.cfg.run
        key, layouts = ("run.validation_layouts", r.validation_layouts) if r.validation_layouts else ("layouts", self.cfg.layouts)
        try:
            return FixedSeedValidator(self.cfg.task, list(layouts) or None, r.validation_episodes, r.validation_seed,
                                      r.sim_threads)
        except ValueError as exc:
            raise ValueError(f"{key} {list(layouts)}: {exc}") from None

    def validate(self) -> dict[str, float]:
        r = self.cfg.run
        policy = trained_team(ActorPolicy(self.model.actor, self.cfg.name), self.cfg.task, self.cfg.shield, self.cfg.residual,
                              self.cfg.belief)
        summary, records = self._validator.run(policy)
        # the best-checkpoint tie-break: a collision or timeout counts as max_steps, as in every
        # comparison here, so that an earlier crash never looks like a faster capture
        summary["capture_steps"] = float(np.mean(capture_steps(records, self.cfg.task.max_steps)))
        self.model.actor.train()
        if r.validation_vs_heuristic:
            if self._heuristic_records is None:  # the same episodes every time: played once per process
                _, self._heuristic_records = self._validator.run(make_policy("heuristic", self.cfg.task))
            summary.update(versus(records, self._heuristic_records, self.cfg.task.max_steps))
        return summary

    def _maybe_best(self, val: dict[str, float], logged: dict | None = None) -> bool:
        """Save best.pt if `val` beats the best so far; `logged` (the row's validation entry, if
        given) says best in the copy best.pt keeps of the pending row."""
        c = self.counters
        better = val["success"] > c.best_success or (val["success"] == c.best_success and val["capture_steps"] < c.best_steps)
        if better:
            if logged is not None:
                logged["best"] = True
            before = c.best_success, c.best_steps, c.best_update
            c.best_success, c.best_steps, c.best_update = val["success"], val["capture_steps"], c.update
            try:
                self.save("best.pt")
            except BaseException:  # best.pt was not replaced: the counters must not say it was
                c.best_success, c.best_steps, c.best_update = before
                raise
        return better

    # ------------------------------------------------------------------ the loop

    def _base_lr(self) -> float:
        return self.cfg.imitation.lr if self.cfg.algo == "dagger" else self.cfg.ppo.lr

    def learning_rate(self) -> float:
        if not self.cfg.ppo.lr_decay:
            return self._base_lr()
        return self._base_lr() * max(1.0 - self.progress(), 0.0)

    def progress(self) -> float:
        """Fraction of the run done: by steps, or by time when max_minutes ends it sooner."""
        frac = self.counters.world_steps / self.cfg.total_steps
        if self.cfg.max_minutes > 0:
            frac = max(frac, self.counters.seconds / (60.0 * self.cfg.max_minutes))
        return min(frac, 1.0)

    def _next_rollout(self) -> tuple[Rollout, RolloutStats]:
        """The rollout the next update learns from, with what it saw (stats.seconds: collection time)."""
        if self.overlap:
            if self.worker is None:
                self.worker = self._start_rollout_worker()
            try:
                buf, stats = self.worker.result(self.model)
                self.worker.start(self.model)  # the next rollout, collected while this one is learned from
            except WorkerExited as exc:  # killed (the out-of-memory killer): the run folder is as last saved
                raise ValueError(f"{exc}; {self._kept('')}") from None
            return buf, stats
        if self.split_update and self.critic_worker is None:  # it starts up while the rollout is collected
            self._start_critic_worker()
        torch.set_num_threads(1)  # per-step forwards of a few dozen rows: threads only add overhead
        if self.demos is not None:
            self.collector.beta = teacher_share(self.cfg.imitation, self.counters.update)
        else:
            self.collector.teaching = teacher_labels_needed(self.cfg.ppo, self.counters.update)
        t0 = time.perf_counter()
        stats = self.collector.collect(self.buffer)
        stats.seconds = time.perf_counter() - t0
        return self.buffer, stats

    def _start_rollout_worker(self) -> RolloutWorker:
        """The rollout worker (run.overlap), its env and noise seeded from the update it starts at, like a
        resumed run's. ValueError naming run.overlap where it cannot start: its buffers live in shared
        memory, which a full /dev/shm or the open-file limit refuses (torch's RuntimeError), or no
        process can be made (OSError)."""
        buf = self.buffer
        try:
            return RolloutWorker(self.cfg, self.counters.update, buf.T, buf.W, buf.N, self.env.obs_dim,
                                 buf.states.shape[-1])
        except (OSError, RuntimeError) as exc:
            raise ValueError(f"run.overlap: the rollout worker rollout-{self.cfg.name} could not start ({exc}); a run "
                             f"started with --set run.overlap=false collects in this process instead; "
                             f"{self._kept('once the worker can start')}") from None

    def _start_critic_worker(self) -> None:
        """Start the critic's process (run.split_update); where it cannot start (no shared memory,
        no processes allowed), say why and update in this process instead: training goes on."""
        try:
            self.critic_worker = CriticWorker(self.model, self.cfg, self.buffer.n_transitions, self.update_threads)
        except (OSError, RuntimeError) as exc:
            self.split_update = False
            self.update_threads = self.cfg.run.update_threads(self.overlap, usable_cores(), split=False)
            self.log(f"[train] note: the critic process could not start ({exc}); the update runs in this process "
                     f"(--set run.split_update=false says so from the start)")

    def close(self) -> None:
        """Stop the rollout worker, if one runs, finish metrics.rrd and release the run folder (train()
        does this when it returns)."""
        self._stop_helpers()
        if self._lock is not None:
            self._lock.close()  # releases the run folder
            self._lock = None

    def _stop_helpers(self) -> None:
        """Stop the child processes, if any run, and finish metrics.rrd."""
        if self.worker is not None:
            self.worker.close()
            self.worker = None
        if self.critic_worker is not None:
            self.critic_worker.close()
            self.critic_worker = None
        if self.rerun is not None:
            try:
                self.rerun.close()
            except ValueError as exc:  # its last rows did not fit on the disk; metrics.jsonl holds them
                self.log(f"note: {exc}; metrics.jsonl holds every row")

    def _remove_a_run_that_holds_nothing(self) -> None:
        """After the run failed: when its folder holds no checkpoint and no logged update (it failed in
        its first update: training diverged, a reward term raised), remove the files this run made
        there (RUN_FILES, and its lock file while it still holds it) and the folder if this run made it
        and nothing else is in it: nothing there could be resumed or read. A folder with logged
        updates keeps them (they show how the run failed); files that were there stay."""
        log_size = self.metrics.path.stat().st_size if self.metrics.path.is_file() else 0
        if self._lock is None or log_size or any((self.run_dir / n).exists() for n in ("last.pt", "best.pt")):
            return
        self._stop_helpers()  # metrics.rrd finished before it goes
        for name in set(RUN_FILES) - self._found:
            with contextlib.suppress(OSError):
                (self.run_dir / name).unlink(missing_ok=True)
        release_lock(self._lock, self.run_dir / ".lock", remove_file=self._new_lock)
        self._lock = None
        if self._made_folder:
            with contextlib.suppress(OSError):
                self.run_dir.rmdir()  # only when empty: a file put there meanwhile keeps it
                self.log(f"[train] removed the run folder {self.run_dir}: it held no checkpoint and no logged update")

    def train_one_update(self) -> dict:
        """Collect one rollout (or take the one collected meanwhile, with overlap), learn from it,
        advance the counters; returns the metrics row."""
        cfg, c = self.cfg, self.counters
        t0 = time.perf_counter()
        buf, stats = self._next_rollout()
        self.buffer = buf
        torch.set_num_threads(self.update_threads)
        t1 = time.perf_counter()
        lr = self.learning_rate()
        for group in self.optimizer.param_groups:
            group["lr"] = lr
        self._consistent = False
        warming_up = c.update < cfg.ppo.critic_warmup  # the critic learns alone: the actor is held
        meta_grad = None
        if cfg.ppo.learnable_gamma:  # held with the actor: its meta-gradient assumes the actor's step
            meta_grad = 0.0 if warming_up else self._learn_discount()
        try:
            if self.demos is not None:
                losses = imitation_update(self.model, self.optimizer, self.demos, buf, cfg.imitation, cfg.ppo,
                                          self.discount.value, self.generator, critic_worker=self.critic_worker)
                losses["teacher_share"] = self.collector.beta
            else:
                weight = teacher_weight(cfg.ppo, c.update)
                losses = ppo_update(self.model, self.optimizer, buf, cfg.ppo, self.discount.value, self.generator,
                                    lagged=self.overlap, anchor=self.anchor, critic_worker=self.critic_worker,
                                    critic_only=warming_up, teacher_weight=weight)
                if cfg.ppo.teacher_coef > 0:
                    losses["teacher_weight"] = weight
        except WorkerExited as exc:  # the critic's process was killed (the out-of-memory killer): the run folder is as last saved
            self.critic_worker.close()
            self.critic_worker = None
            raise ValueError(f"{exc}; {self._kept('')}") from None
        t2 = time.perf_counter()
        self._check_finite(losses)
        c.update += 1
        c.world_steps += buf.T * buf.W
        c.agent_steps += buf.n_transitions
        c.episodes += len(stats.episodes)
        c.seconds += t2 - t0
        self.recent.extend(stats.episodes)
        row = {
            "update": c.update, "world_steps": c.world_steps, "agent_steps": c.agent_steps, "episodes": c.episodes,
            "seconds": round(c.seconds, 3), "lr": lr, "gamma": self.discount.value,
            "rollout_s": stats.seconds, "wait_s": t1 - t0, "update_s": t2 - t1, "wall_s": t2 - t0,
            "agent_steps_per_s": buf.n_transitions / max(t2 - t0, 1e-9),
            "rollout_agent_steps_per_s": buf.n_transitions / max(stats.seconds, 1e-9),
            "update_agent_steps_per_s": buf.n_transitions / max(t2 - t1, 1e-9),
            "train": summarise(stats.episodes) if stats.episodes else {},
            "reward_terms_per_step": stats.reward_terms,
            "episode_returns": _mean_returns(stats.episodes),
            "loss": losses,
        }
        if meta_grad is not None:
            row["gamma_meta_grad"] = meta_grad
        # from here a checkpoint holds this update, and its row until the row is in the log
        self._pending_row = row
        self._consistent = True
        return row

    def _check_finite(self, losses: dict) -> None:
        """Refuse an update that left a weight NaN or infinite (training diverged), before any
        checkpoint holds it: last.pt keeps the update before, from which a new run can start."""
        bad = next((name for name, p in self.model.named_parameters() if not torch.isfinite(p).all()), None)
        if bad is None:
            return
        section = "imitation" if self.demos is not None else "ppo"  # whose lr and max_grad_norm drove the update
        lr_key, lr = f"{section}.lr", getattr(self.cfg, section).lr
        shown = ", ".join(f"{k} {v:.3g}" for k, v in losses.items() if k in ("policy_loss", "bc_loss", "value_loss", "grad_norm"))
        kept = self.diverged_hint(self.run_dir / "last.pt" if self._saved_update > 0 else None, self._saved_update, lr_key)
        raise ValueError(f"training diverged at update {self.counters.update + 1}: the weights {bad} are no longer finite "
                         f"(losses: {shown or 'none'}); {kept}. Try a lower {lr_key} (now {lr:g}) or {section}.max_grad_norm")

    def _why_done(self) -> str:
        """What ended the run already, for a resume that finds nothing left to do."""
        c, cfg = self.counters, self.cfg
        if cfg.max_minutes > 0 and c.seconds >= 60.0 * cfg.max_minutes and c.world_steps < cfg.total_steps:
            return (f"nothing to train: the run has used its max_minutes {cfg.max_minutes:g} ({c.seconds / 60:.1f} min); "
                    f"resume with a larger --max-minutes (or 0 for none) to go on")
        return (f"nothing to train: the run has reached total_steps {cfg.total_steps} ({c.world_steps} world steps); "
                f"resume with a larger --total-steps to go on")

    def _validation_due(self) -> bool:
        """Whether the update just made is validated: every run.validate_every and the last."""
        every = self.cfg.run.validate_every
        return bool(every and self.counters.update % every == 0) or self.progress() >= 1.0

    def _logged_validation(self) -> dict:
        """The newest validation in the metrics log ({} if none)."""
        for row in reversed(self.metrics.rows()):
            if row.get("validation"):
                return {k: v for k, v in row["validation"].items() if k not in ("best", "seconds")}
        return {}

    def _validate_into(self, row: dict, bar, last_val: dict) -> dict:
        """Validate the current policy; the result goes into `row` (and best.pt if it is the best)."""
        c = self.counters
        advance_bar(bar, row, self.recent, last_val, self.progress(), note="validating")
        t0 = time.perf_counter()
        val = self.validate()
        spent = time.perf_counter() - t0
        c.seconds += spent
        c.validation_seconds += spent
        row["validation"] = dict(val, best=False, seconds=spent)  # in the row first: best.pt holds it
        try:
            row["validation"]["best"] = self._maybe_best(val, row["validation"])
        except BaseException:  # best.pt not replaced: a resume validates this update again
            del row["validation"]
            raise
        return val

    def _log_row(self, row: dict, bar, last_val: dict) -> None:
        """Append an update's row to the log (and rerun), then checkpoint on schedule."""
        try:
            self.metrics.append(row)
        except ValueError as exc:
            raise self._cannot_write(exc) from None
        self._pending_row = {}
        if self.rerun is not None:
            try:
                self.rerun.log(int(row["world_steps"]), row)
            except ValueError as exc:  # metrics.rrd on a full disk; the row is in metrics.jsonl
                raise self._cannot_write(exc) from None
        if self.counters.update % self.cfg.run.checkpoint_every == 0:  # after the log: a resume truncates the log to it
            self.save()
        advance_bar(bar, row, self.recent, last_val, self.progress())

    def _cannot_write(self, exc: ValueError) -> ValueError:
        """exc (a file of the run could not be written) with what the run folder still holds."""
        return ValueError(f"{exc}; {self._kept('once the folder has room and write access')}")

    def _kept(self, once: str) -> str:
        """What the run folder holds after a stop, and how to go on `once` a condition is met ('' if none)."""
        if self._saved_update >= 0:
            return f"last.pt keeps update {self._saved_update}; {once + ', ' if once else ''}continue with: {self.resume_command}"
        return f"no checkpoint was written yet: start the run again{' ' + once if once else ''}"

    def _learn_discount(self) -> float:
        buf = self.buffer
        _, _, s = advantages_and_returns(buf, self.discount.value, self.cfg.ppo.gae_lambda)
        T, B = buf.T, buf.W * buf.N
        n = T * B
        sample = torch.randperm(n, generator=self.generator)[: min(self.cfg.ppo.minibatch_size, n)]
        return self.discount.meta_step(
            self.model.actor, self.spec, buf.obs.reshape(T, B, -1), buf.actions.reshape(T, B, 2),
            s["rewards"], s["values"], s["next_values"], s["terminated"], s["done"],
            self.cfg.ppo.gae_lambda, max(self.learning_rate(), 1e-8), sample,
        )

    def _start_session(self) -> tuple:
        """What train() does before its first update: config.yaml, the log of a run stopped before its
        first checkpoint cut, the progress bar; returns (bar, the log's last validation)."""
        cfg = self.cfg
        self.run_dir.mkdir(parents=True, exist_ok=True)
        nothing_left = self.progress() >= 1.0 and not self._pending_row
        if not (nothing_left and self._saved_update >= 0):  # a resume that trains nothing leaves it as last.pt has it
            try:
                atomic_write_text(self.run_dir / "config.yaml", dump_yaml(cfg))
            except ValueError as exc:
                raise self._cannot_write(exc) from None
        if self._saved_update < 0 and self.metrics.path.is_file() and self.metrics.path.stat().st_size:
            # rows (or a cut-off line) of a run killed before its first checkpoint: it starts afresh, and so does its log
            self.log(f"{self.metrics.path}: dropping {len(self.metrics.rows())} rows of a run stopped before its first checkpoint")
            self.metrics.truncate_after(0)
        bar = progress_bar(cfg, self.progress())
        last_val = self._logged_validation()  # a resumed run's last one, until this session validates
        if nothing_left:
            self.log(self._why_done())
        return bar, last_val

    def train(self, stop_requested: Callable[[], bool] | None = None) -> dict:
        """Train until total_steps; returns {'status': 'done'|'interrupted', counters, last validation}.

        Ctrl-C (KeyboardInterrupt) interrupts. So does any error raised once stop_requested()
        is true: a stop signal that lands inside a library call can come out as that call's own
        error (mujoco's bindings turn it into a TypeError), and it must still save and say how
        to resume."""
        c = self.counters
        bar, last_val, status = None, {}, "done"
        try:  # from the first line: a Ctrl-C while the session starts (reading a long log) is an interrupt too
            bar, last_val = self._start_session()
            if self._pending_row:  # the last update's row never reached the log (interrupted): log it now
                row = self._pending_row
                if "validation" not in row and self._validation_due():
                    last_val = self._validate_into(row, bar, last_val)
                self._log_row(row, bar, last_val)
                self.save()  # last.pt without the pending row: it is in the log now
            while self.progress() < 1.0:
                row = self.train_one_update()  # pending until _log_row
                if self._validation_due():
                    last_val = self._validate_into(row, bar, last_val)
                self._log_row(row, bar, last_val)
            if self._saved_update != c.update:
                self.save()
        except (KeyboardInterrupt, Exception) as exc:
            if not isinstance(exc, KeyboardInterrupt) and not (stop_requested is not None and stop_requested()):
                self._remove_a_run_that_holds_nothing()
                raise
            status = "interrupted"
            if isinstance(exc, KeyboardInterrupt):
                interrupt_handled()  # returned as a status: the process must not end by SIGINT for it
            if self._consistent and (self._saved_update != c.update or self._pending_row):
                try:
                    self.save()
                except KeyboardInterrupt:  # a second Ctrl-C: the save is atomic, so last.pt is the one before, whole
                    self.log(f"\nsecond interrupt: the save of update {c.update} was cut short")
            if (self.run_dir / "last.pt").is_file():
                self.log(f"\ninterrupted: state of update {self._saved_update} is in {self.run_dir / 'last.pt'}; "
                         f"continue with: {self.resume_command}")
            else:  # stopped before the first checkpoint: there is nothing to resume
                self.log(f"\ninterrupted before the first checkpoint: nothing to resume in {self.run_dir}; "
                         f"run the same command again to start afresh")
        finally:
            self.close()
            if bar is not None:
                bar.close()
        return {"status": status, "counters": dataclasses.asdict(c), "validation": last_val, "run_dir": str(self.run_dir)}


#: the files a run writes in its folder beside its checkpoints and lock (_start_session, _build)
RUN_FILES = ("config.yaml", "metrics.jsonl", "metrics.rrd")


def read_counters(data: dict, path: Path) -> Counters:
    """A checkpoint's counters (ValueError naming `path` if one is unknown or not a number); a
    counter added since the file was written keeps its default."""
    stored = data["counters"]
    fields = {f.name: f.type for f in dataclasses.fields(Counters)}
    unknown = sorted(set(stored) - set(fields))
    if unknown:
        raise ValueError(f"checkpoint {path}: unknown counters {unknown} (known: {', '.join(fields)})")
    for name, value in stored.items():
        whole = fields[name] == "int"
        if isinstance(value, bool) or not isinstance(value, int if whole else (int, float)):
            raise ValueError(f"checkpoint {path}: counter {name} is {value!r}, expected {'a whole number' if whole else 'a number'}")
        least = -1 if name in ("best_success", "best_update") else 0  # -1: no validation yet
        if value < least:
            raise ValueError(f"checkpoint {path}: counter {name} is {value!r}, expected at least {least}")
    return Counters(**stored)


def _mean_returns(episodes) -> dict[str, float]:
    if not episodes:
        return {}
    keys = episodes[0].returns.keys()
    return {k: float(np.mean([e.returns[k] for e in episodes])) for k in keys}


