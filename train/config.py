"""The training config: one frozen dataclass per concern, nested in `TrainConfig`.

YAML files under configs/train/ and `--set key=value` overrides go through
`load_train_config`, the same path as the task config (pursuit_mj.configio). A train config
embeds the task it trains on under `task:`; `task_file:` may name a task YAML (or a preset
such as `hard`). Files apply in order, each as a layer: its task_file's keys over the task so
far, then its own `task:` keys. `--set task_file=X` is a layer over every file; flags and the
other `--set` keys (`--set task.x=`) apply over it.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import Any, Collection, Mapping, Sequence

from pursuit_mj.config import TaskConfig, found_code_ref, load_task_yaml, preset_or_file
from pursuit_mj.file_kinds import refuse_another_kind
from pursuit_mj.configio import ConfigError, build, check_values, found_beside, key_where, load, load_yaml, merge, parse_override, spec, to_dict
from pursuit_mj.layout import N_BUILTIN, found_layout_ref
from pursuit_mj.sensing import PRIVILEGED_VIEWS
from pursuit_mj.user_file import is_file_reference, split_reference

REGIMES = ("classic", "full_obs", "fine_tune", "mappo", "custom")


@dataclasses.dataclass(frozen=True)
class PPOConfig:
    """PPO / MAPPO hyperparameters (DESIGN.md section 6 defaults)."""

    lr: float = spec(3e-4, lo=0.0, lo_open=True, help="Adam learning rate at the start (decays linearly to 0 if lr_decay)")
    lr_decay: bool = spec(True, help="decay the learning rate linearly to zero over total_steps")
    gamma: float = spec(0.99, lo=0.0, hi=1.0, help="discount factor per decision step")
    gae_lambda: float = spec(0.95, lo=0.0, hi=1.0, help="GAE lambda")
    clip: float = spec(0.2, lo=0.0, lo_open=True, hi=1.0, help="PPO ratio clip epsilon")
    epochs: int = spec(10, lo=1, hi=100, help="passes over each rollout batch")
    batch_size: int = spec(1024, lo=2, hi=2**20, help="pursuer transitions per update (rollout length = ceil(batch / (n_envs * pursuers)))")
    minibatch_size: int = spec(256, lo=1, help="pursuer transitions per gradient step")
    ent_coef: float = spec(0.0, lo=0.0, help="weight of the entropy bonus")
    vf_coef: float = spec(0.5, lo=0.0, help="weight of the value loss")
    max_grad_norm: float = spec(0.5, lo=0.0, lo_open=True, help="gradient-norm clip (of what: grad_clip)")
    grad_clip: str = spec("joint", choices=("joint", "separate"),
                          help="joint: max_grad_norm bounds the norm of actor and critic gradients together (the "
                               "reference study, CleanRL); separate: each network's own (MAPPO's way), so a large "
                               "value gradient no longer shrinks the policy's step")
    norm_adv: bool = spec(True, help="normalise advantages per minibatch (zero mean, unit std)")
    value_scaling: bool = spec(True, help="PPO: divide the value loss by the std of the value targets (reference study)")
    learnable_gamma: bool = spec(False, help="learn the discount by meta-gradient (see train/discount.py); gamma is its start")
    gamma_meta_lr: float = spec(3e-3, lo=0.0, lo_open=True, help="Adam step size for the discount's logit")
    gamma_outer: float = spec(0.995, lo=0.0, hi=1.0, help="fixed discount of the meta objective that judges gamma")
    anchor_coef: float = spec(0.0, lo=0.0, help="weight of KL(policy || anchor) in the loss, the anchor being the init_from "
                                                "actor, frozen: PPO improves on its start without drifting far from it (0: off)")
    critic_warmup: int = spec(0, lo=0, help="updates at the start of a run in which only the critic learns and the actor "
                                            "is held: for a start whose critic is fresh (a policy-only export)")
    teacher_coef: float = spec(0.0, lo=0.0, help="weight of the squared distance between the actor's mean and the heuristic "
                                                 "team's action on each rollout observation (kickstarting; the team labels, "
                                                 "never drives; 0: off)")
    teacher_updates: int = spec(0, lo=0, help="updates over which the teacher's weight falls linearly from teacher_coef to 0 "
                                              "(0: it stays at teacher_coef)")
    teacher_from_step: int = spec(0, lo=0, help="the teacher's labels count only for observations met this many decision "
                                                "steps or more into their episode: a pull toward the team in long chases, "
                                                "none in the rest (0: everywhere)")



#: PPOConfig keys only PPO's update reads (DAgger reads gamma, gae_lambda, batch_size, vf_coef, value_scaling, lr_decay)
PPO_UPDATE_ONLY = ("lr", "clip", "epochs", "minibatch_size", "ent_coef", "max_grad_norm", "grad_clip", "norm_adv", "anchor_coef",
                   "critic_warmup", "teacher_coef", "teacher_updates", "teacher_from_step")


@dataclasses.dataclass(frozen=True)
class ImitationConfig:
    """DAgger from a teacher team (`algo: dagger`, see train/imitation.py)."""

    teacher: str = spec("heuristic", choices=("heuristic",), help="the team whose actions the student learns")
    teacher_sees: str = spec("same", choices=("same", *PRIVILEGED_VIEWS),
                             help="what the teacher perceives: same (the student's observations), all_round (360 deg, "
                                  "exact, no misses: pursuit_mj.sensing.PRIVILEGED_VIEWS) or full (everything, exactly); "
                                  "a privileged teacher labels the student's observations with what it would do knowing more")
    lr: float = spec(1e-3, lo=0.0, lo_open=True, help="Adam learning rate at the start (decays like ppo.lr if ppo.lr_decay)")
    beta_start: float = spec(1.0, lo=0.0, hi=1.0, help="chance that the teacher drives a world at a decision step, in the first update")
    beta_updates: int = spec(20, lo=0, help="updates over which the teacher's share falls linearly to 0")
    dataset_size: int = spec(400_000, lo=1, hi=5_000_000, help="pursuer observations kept (the oldest are dropped first)")
    grad_steps: int = spec(60, lo=1, help="gradient steps per update")
    minibatch_size: int = spec(1024, lo=1, help="demonstrations (and rollout transitions for the critic) per gradient step")
    max_grad_norm: float = spec(1.0, lo=0.0, lo_open=True, help="global gradient-norm clip")
    loss: str = spec("mse", choices=("mse", "heading_speed", "heading_median_speed"),
                     help="mse: squared error of the action; heading_speed: heading and speed fitted apart, so a "
                          "student unsure of the direction still flies at its teacher's speed; heading_median_speed: the "
                          "same with the median of its speeds, not their mean (train/imitation.py)")


@dataclasses.dataclass(frozen=True)
class ResidualConfig:
    """Residual policy learning (pursuit_mj/residual.py): the actor learns a correction added to a base team."""

    base: str = spec("none", choices=("none", "heuristic"),
                     help="team whose actions the actor corrects (none: the actor alone drives)")
    scale: float = spec(0.3, lo=0.0, lo_open=True, hi=2.0, help="weight of the actor's output in the sum, in fractions of max speed")


MAX_WIDTH = 4096  # widest network layer accepted: far beyond any use here, so a slip of a few zeros fails early


NET_KINDS = ("reference", "mlp")  # the keys of train/networks.py TRUNKS (a test keeps the two lists one)


@dataclasses.dataclass(frozen=True)
class NetConfig:
    """Network shape. `reference`: per-entity encoders with masked mean pooling (DESIGN.md 6)."""

    kind: str = spec("reference", choices=NET_KINDS, help="actor/critic network family (train/networks.py TRUNKS)")
    encoder_width: int = spec(128, lo=1, hi=MAX_WIDTH, help="width of each per-entity encoder")
    hidden: tuple[int, ...] = spec((128, 128), help="widths of the fused trunk after the encoders")
    use_rays: bool = spec(True, help="encode the range readings (the reference study had none)")
    init_log_std: float = spec(-0.5, lo=-5.0, hi=2.0, help="initial log std of the Gaussian head")
    critic_hidden: tuple[int, ...] = spec((256, 256), help="MAPPO centralised critic widths")

    def validate(self, source: str = "config") -> None:
        for key, widths in (("hidden", self.hidden), ("critic_hidden", self.critic_hidden)):
            if not widths or any(not 1 <= h <= MAX_WIDTH for h in widths):
                raise ConfigError(f"{key_where(source, key)}: {list(widths)} is not a list of widths 1-{MAX_WIDTH}")


def check_indices(key: str, refs: Sequence[int | str], source: str) -> None:
    """ConfigError naming `key` and `source` for a built-in layout index out of range in `refs` (files
    are loaded only as a run starts: `TrainConfig.check_layouts`)."""
    for ref in refs:
        if isinstance(ref, int) and not 0 <= ref < N_BUILTIN:
            raise ConfigError(f"{key_where(source, key)}: {ref} is not a built-in layout index (0-{N_BUILTIN - 1}) or a file")


def usable_cores() -> int:
    """CPUs this process may run on: its affinity mask (taskset, containers) where the OS has one."""
    if hasattr(os, "sched_getaffinity"):
        return max(1, len(os.sched_getaffinity(0)))
    return os.cpu_count() or 1


@dataclasses.dataclass(frozen=True)
class RunConfig:
    """Where and how often: run folder, validation, checkpoints, logging, threads."""

    runs_dir: str = spec("runs", help="parent folder of run folders (runs/<name>/)")
    validate_every: int = spec(10, lo=0, help="updates between validations (0 = only the one every run ends with, which writes best.pt)")
    validation_episodes: int = spec(24, lo=1, hi=10000, help="episodes per validation (fixed seeds)")
    validation_seed: int = spec(10_000, lo=0, hi=2**62, help="first seed of the fixed validation set")
    validation_layouts: tuple[int | str, ...] = spec((), help="layouts to validate on (empty: the training layouts)")
    validation_vs_heuristic: bool = spec(True, help="play the validation episodes once with the heuristic team too, and "
                                                    "report every validation paired with it, episode by episode")
    checkpoint_every: int = spec(1, lo=1, help="updates between 'last' checkpoints (1: lose at most one update)")
    torch_threads: int = spec(0, lo=0, hi=256, help="torch threads for the update, per process (0: the cores left idle "
                                                  "meanwhile: all of them in turn, half each with split_update, one fewer "
                                                  "with overlap); the rollout uses 1")
    split_update: bool = spec(True, help="learn the critic in a child process while the actor learns in this one "
                                         "(train/critic_worker.py), when collecting in turn on 2+ cores (not with run.overlap): "
                                         "1.15-1.8x faster updates at minibatches of 256 on 2 cores, little at 1024 (docs/training.md); "
                                         "same results up to float rounding")
    overlap: bool = spec(False, help="collect the next rollout in a child process while the update runs (train/rollout_worker.py): "
                                     "a training step costs about the longer of the two on 2+ cores, at one update of policy lag "
                                     "(corrected by the decoupled PPO objective); ppo and mappo only (dagger always collects in turn)")
    sim_threads: int = spec(0, lo=0, hi=256, help="mujoco.batch threads (0: its default)")
    progress: bool = spec(True, help="show the tqdm progress bar")
    rerun: bool = spec(False, help="also stream every logged scalar to <run>/metrics.rrd (open with `rerun`), on a "
                                   "world_steps timeline (decision steps x worlds, as in metrics.jsonl)")

    def validate(self, source: str = "config") -> None:
        check_indices("validation_layouts", self.validation_layouts, source)
        if not self.runs_dir.strip():  # Path("") is the current folder: runs would land among the user's files
            raise ConfigError(f"{key_where(source, 'runs_dir')}: empty; name a folder (default runs)")

    def update_threads(self, overlapped: bool, cores: int | None = None, split: bool = False) -> int:
        """Torch threads for the update, per process: torch_threads when set, else the cores idle
        during it (all of them when collection waits for the update, half of them each when the
        critic learns in a child process, one fewer when a rollout worker collects meanwhile), at
        least 1. cores: the CPUs this process may run on unless given."""
        if self.torch_threads:
            return self.torch_threads
        cores = cores or usable_cores()
        if overlapped:
            return max(1, cores - 1)
        return max(1, cores // 2) if split else cores


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """One training run: the regime, the task it trains on, and every learning setting."""

    name: str = spec("run", help="run name; outputs go to <run.runs_dir>/<name>/")
    regime: str = spec("custom", choices=REGIMES, help="label of the reference regime this run follows")
    algo: str = spec("ppo", choices=("ppo", "mappo", "dagger"),
                     help="ppo: per-agent critic; mappo: centralised critic on the global state; dagger: imitate imitation.teacher (a warm start for ppo)")
    seed: int = spec(0, lo=0, hi=2**62, help="seed of networks, sampling and environment resets")
    total_steps: int = spec(1_000_000, lo=1, help="world decision steps to train for (summed over worlds)")
    max_minutes: float = spec(0.0, lo=0.0, help="stop after this much training time (0 = none); the LR decays over whichever ends first")
    n_envs: int = spec(6, lo=1, hi=4096, help="worlds stepped together")
    layouts: tuple[int | str, ...] = spec((), help="training layouts, one chosen per world in turn (empty: task.layout)")
    init_from: str | None = spec(None, help="checkpoint whose actor/critic weights start this run (fine_tune)")
    shield: bool = spec(False, help="act behind the safety shield (pursuit_mj/shield.py) in training and validation; "
                                    "load_policy puts it back on the trained policy")
    belief: bool = spec(False, help="append belief features (pursuit_mj/belief.py: remembered evaders, coverage-search "
                                    "waypoint) to the actor's and critic's observations; load_policy adds them back")
    rewards: tuple[str, ...] = spec((), help="reward terms of your own, FILE.py:NAME each: the function NAME of FILE, "
                                             "called every step with a StepView (pursuit_mj/custom_rewards.py), is paid beside "
                                             "the task's terms in training and logged under NAME (docs/training.md)")
    task_file: str | None = spec(None, help="task YAML file or preset name: its keys apply over the task of the files before, under this "
                                          "file's own task: keys (--set task_file: over every file, under the other --set keys)")
    task: TaskConfig = spec(default_factory=TaskConfig, help="the task trained on")
    ppo: PPOConfig = spec(default_factory=PPOConfig, help="PPO hyperparameters")
    imitation: ImitationConfig = spec(default_factory=ImitationConfig, help="DAgger settings (algo dagger)")
    residual: ResidualConfig = spec(default_factory=ResidualConfig, help="learn a correction to a base team (residual.base)")
    net: NetConfig = spec(default_factory=NetConfig, help="network shape")
    run: RunConfig = spec(default_factory=RunConfig, help="run folder, validation, checkpoints")

    def validate(self, source: str = "config") -> None:
        """Per-field checks run at every override; cross-field ones run in `check_complete`."""
        if not self.name or "/" in self.name or self.name in (".", ".."):
            raise ConfigError(f"{key_where(source, 'name')}: {self.name!r} is not a usable run folder name")
        check_indices("layouts", self.layouts, source)
        for ref in self.rewards:
            if not is_file_reference(ref):
                raise ConfigError(f"{key_where(source, 'rewards')}: {ref!r} is not FILE.py:NAME (a Python file and the "
                                  f"function in it)")
        if self.regime == "fine_tune" and not self.init_from:
            raise ConfigError(f"{source}: regime fine_tune needs init_from (a full_obs checkpoint)")

    def check_complete(self, source: str = "train config", key_sources: Mapping[str, str] | None = None) -> None:
        """Checks that span keys set by separate overrides (run once the config is final). An error
        starts with the command-line values that gave the keys it is about, `key_sources[key]` (e.g.
        '--set ppo.batch_size=8', from `key_sources_of`), else with `source`."""
        def where(*keys: str) -> str:
            given = list(dict.fromkeys((key_sources or {})[k] for k in keys if k in (key_sources or {})))
            return ", ".join(given) if given else source

        if not self.task.random_layout:  # world w plays layouts[w % len]: the pool must fit the worlds
            if len(self.layouts) > self.n_envs:
                raise ConfigError(f"{where('layouts', 'n_envs')}: {len(self.layouts)} layouts for n_envs {self.n_envs}: "
                                  f"world w trains on layouts[w % {len(self.layouts)}], so {len(self.layouts) - self.n_envs} "
                                  f"of them would never be trained on (raise n_envs, or set task.random_layout=true)")
            val_key = "run.validation_layouts" if self.run.validation_layouts else "layouts"
            val = self.run.validation_layouts or self.layouts
            if len(val) > self.run.validation_episodes:
                raise ConfigError(f"{where(val_key, 'run.validation_episodes')}: {len(val)} validation layouts for "
                                  f"run.validation_episodes {self.run.validation_episodes}: episode k plays layouts[k % "
                                  f"{len(val)}], so {len(val) - self.run.validation_episodes} of them would never be "
                                  f"validated on (raise run.validation_episodes, or set task.random_layout=true)")
        if self.algo != "dagger" and self.ppo.minibatch_size > self.ppo.batch_size:  # DAgger's is imitation.minibatch_size
            source = where("ppo.minibatch_size", "ppo.batch_size")
            raise ConfigError(f"{source}: ppo.minibatch_size {self.ppo.minibatch_size} exceeds ppo.batch_size {self.ppo.batch_size}")
        if self.algo != "dagger" and self.ppo.anchor_coef > 0 and not self.init_from:
            source = where("ppo.anchor_coef", "init_from")
            raise ConfigError(f"{source}: ppo.anchor_coef {self.ppo.anchor_coef:g} needs init_from: the anchor is the actor "
                              f"the run starts from (set --init-from, or ppo.anchor_coef=0)")
        if self.algo == "dagger" and self.ppo.learnable_gamma:
            source = where("ppo.learnable_gamma", "algo")
            raise ConfigError(f"{source}: ppo.learnable_gamma works with algo ppo or mappo, not dagger (imitation has no policy gradient)")
        if self.ppo.learnable_gamma:
            from .discount import LEARNABLE_START

            lo, hi = LEARNABLE_START
            if not lo <= self.ppo.gamma <= hi:
                source = where("ppo.gamma", "ppo.learnable_gamma")
                raise ConfigError(f"{source}: ppo.gamma {self.ppo.gamma:g} cannot start ppo.learnable_gamma: the learned "
                                  f"discount is sigmoid(logit) and starts in [{lo:g}, {hi:g}] (e.g. ppo.gamma=0.99)")
        if self.algo != "dagger" and self.ppo.teacher_coef > 0 and self.residual.base != "none":
            source = where("ppo.teacher_coef", "residual.base")
            raise ConfigError(f"{source}: ppo.teacher_coef {self.ppo.teacher_coef:g} cannot work with residual.base "
                              f"{self.residual.base!r}: the actor's output is then a correction to that team, not an action "
                              "the teacher would take (set ppo.teacher_coef=0, or residual.base=none)")
        if self.algo == "dagger" and self.residual.base != "none":
            source = where("residual.base", "algo")
            raise ConfigError(f"{source}: residual.base {self.residual.base!r} works with algo ppo or mappo, not dagger "
                              "(a residual starts as its base team; there is nothing to imitate)")
        from pursuit_mj.shield import MIN_RAYS

        if self.task.n_rays < MIN_RAYS:
            named = [(k, key) for k, key, on in (("shield", "shield", self.shield),
                                                 ("residual.base", "residual.base", self.residual.base != "none"),
                                                 ("belief", "belief", self.belief),
                                                 ("algo dagger (its teacher)", "algo", self.algo == "dagger"),
                                                 ("run.validation_vs_heuristic", "run.validation_vs_heuristic",
                                                  self.run.validation_vs_heuristic)) if on]
            users = [k for k, _ in named]
            if users:
                source = where("task.n_rays", *(key for _, key in named))
                raise ConfigError(f"{source}: task.n_rays {self.task.n_rays}: the heuristic team and the shield see walls "
                                  f"only through range readings and need at least {MIN_RAYS}; {', '.join(users)} "
                                  f"{'uses' if len(users) == 1 else 'use'} them (raise task.n_rays, or turn those off)")

    def layout_files(self) -> list[tuple[str, str]]:
        """(key, path) of every layout file the run names (task.layout, layouts,
        run.validation_layouts), in that order; built-in indices are left out."""
        return [(key, str(ref)) for key, refs in layout_refs(self) for ref in refs if _is_file_ref(ref)]

    def with_absolute_files(self) -> "TrainConfig":
        """This config with every layout file, code file (rewards, task.evader.model), the task
        file (task_file, unless a preset's name) and the init_from checkpoint path made absolute
        (from the current folder): the stored config of a run then loads them wherever the run is
        resumed or loaded again."""
        def absolute(ref):
            return os.path.abspath(ref) if _is_file_ref(ref) else ref

        def absolute_code(ref):
            if not is_file_reference(ref):
                return ref  # janosov
            path, name = split_reference(ref, "code")
            return f"{os.path.abspath(path)}:{name}"

        evader = dataclasses.replace(self.task.evader, model=absolute_code(self.task.evader.model))
        task = dataclasses.replace(self.task, layout=absolute(self.task.layout), evader=evader)
        run = dataclasses.replace(self.run, validation_layouts=tuple(absolute(r) for r in self.run.validation_layouts))
        # a task_file is read as preset_or_file reads it: a file from the current folder first, else a preset
        task_file = os.path.abspath(self.task_file) if self.task_file and Path(self.task_file).is_file() else self.task_file
        init_from = os.path.abspath(self.init_from) if self.init_from and Path(self.init_from).is_file() else self.init_from
        return dataclasses.replace(self, task=task, run=run, layouts=tuple(absolute(r) for r in self.layouts),
                                   rewards=tuple(absolute_code(r) for r in self.rewards), task_file=task_file,
                                   init_from=init_from)

    def code_files(self) -> list[tuple[str, str]]:
        """(key, FILE) of every Python file the run's code comes from: each FILE.py:NAME of
        `rewards`, and of task.evader.model when it names one; a file once, at its first key."""
        refs = [("rewards", r) for r in self.rewards]
        if is_file_reference(self.task.evader.model):
            refs.append(("task.evader.model", self.task.evader.model))
        found: dict[str, str] = {}
        for key, ref in refs:
            found.setdefault(split_reference(ref, key)[0], key)
        return [(key, path) for path, key in found.items()]

    def check_code(self, source: str = "train config") -> None:
        """Load every reward term and the evader model the run names: ValueError naming the key and
        the reference of one that cannot be loaded (no such file or name, an error in the file)."""
        from pursuit_mj.custom_rewards import load_reward_files
        from pursuit_mj.evader_models import make_evader_model

        load_reward_files(self.rewards, f"{source}: rewards")
        if is_file_reference(self.task.evader.model):
            make_evader_model(self.task, 1, self.seed, f"{source}: task.evader.model")

    def check_layouts(self, source: str = "train config", key_sources: Mapping[str, str] | None = None) -> None:
        """Load every layout the run names (task.layout, layouts, run.validation_layouts): ConfigError
        naming the key of one that cannot be (no such index or file, a malformed file), after
        `key_sources[key]` where given (e.g. '--set task.layout=x.yaml'), else after `source`."""
        from pursuit_mj.layout import load_layout

        for key, refs in layout_refs(self):
            for ref in refs:
                try:
                    load_layout(ref)
                except ValueError as exc:
                    shown = ref if key == "task.layout" else list(refs)
                    raise ConfigError(f"{(key_sources or {}).get(key, source)}: {key} {shown}: {exc}") from None

    def _idle_net_settings(self, default: NetConfig) -> list[str]:
        """The changed net.* shape settings that net.kind's trunk does not use: those its
        SHAPE_KEYS (train/networks.py) leave out; a trunk without SHAPE_KEYS uses them all."""
        from .networks import TRUNKS  # here: train.networks imports this module
        from .run_checks import ACTOR_SHAPE_KEYS

        used = getattr(TRUNKS.get(self.net.kind), "SHAPE_KEYS", ACTOR_SHAPE_KEYS)
        changed = [k for k in ACTOR_SHAPE_KEYS if k != "kind" and k not in used and getattr(self.net, k) != getattr(default, k)]
        if not changed:
            return []
        why = ("the reference network's entity encoders" if self.net.kind == "mlp" else
               f"its trunk's weights do not depend on {'it' if len(changed) == 1 else 'them'}: SHAPE_KEYS in train/networks.py")
        return [f"net.{', net.'.join(changed)} {_do(changed)} nothing under net.kind {self.net.kind} ({why})"]

    def idle_settings(self) -> list[str]:
        """Settings changed from their defaults that this combination never reads, one line each
        (not errors: a study's --train-set gives every arm the same values)."""
        default = TrainConfig()
        idle = []
        if self.residual.base == "none" and self.residual.scale != default.residual.scale:
            idle.append(f"residual.scale {self.residual.scale:g} does nothing without residual.base")
        idle += self.task.idle_settings("task.")  # perception keys under full observability, drone_mass under point
        if self.algo == "mappo" and self.ppo.value_scaling != default.ppo.value_scaling:
            idle.append("ppo.value_scaling does nothing under algo mappo (its centralised critic normalises values)")
        if self.algo != "mappo" and self.net.critic_hidden != default.net.critic_hidden:
            idle.append(f"net.critic_hidden {list(self.net.critic_hidden)} does nothing under algo {self.algo} (it sizes MAPPO's critic)")
        idle += self._idle_net_settings(default.net)
        if not self.ppo.learnable_gamma:
            changed = [k for k in ("gamma_meta_lr", "gamma_outer") if getattr(self.ppo, k) != getattr(default.ppo, k)]
            if changed:
                idle.append(f"ppo.{', ppo.'.join(changed)} {_do(changed)} nothing without ppo.learnable_gamma (they tune the learned discount)")
        if self.algo != "dagger" and self.ppo.teacher_coef == 0 and self.ppo.teacher_updates != default.ppo.teacher_updates:
            idle.append(f"ppo.teacher_updates {self.ppo.teacher_updates} does nothing without ppo.teacher_coef (it schedules "
                        "the teacher's weight)")
        if self.algo != "dagger" and self.ppo.teacher_coef == 0 and self.ppo.teacher_from_step != default.ppo.teacher_from_step:
            idle.append(f"ppo.teacher_from_step {self.ppo.teacher_from_step} does nothing without ppo.teacher_coef (it says "
                        "where the teacher's labels count)")
        if self.algo != "dagger" and self.ppo.teacher_coef > 0 and self.ppo.teacher_from_step >= self.task.max_steps:
            idle.append(f"ppo.teacher_coef {self.ppo.teacher_coef:g} does nothing with ppo.teacher_from_step "
                        f"{self.ppo.teacher_from_step} and task.max_steps {self.task.max_steps} (no episode runs that long, "
                        "so no label counts)")
        if self.algo == "dagger" and self.run.overlap:
            idle.append("run.overlap does nothing under algo dagger (it always collects in turn: the teacher's labels feed the update)")
        if not self.run.split_update and self.run.overlap and self.algo != "dagger":
            idle.append("run.split_update false does nothing with run.overlap (its update runs in one process)")
        if self.algo == "dagger":
            im, never = self.imitation, "(the teacher never drives; it labels only)"
            if im.beta_updates == 0 and im.beta_start != default.imitation.beta_start:
                idle.append(f"imitation.beta_start {im.beta_start:g} does nothing with imitation.beta_updates 0 {never}")
            if im.beta_start == 0 and im.beta_updates != default.imitation.beta_updates:
                idle.append(f"imitation.beta_updates {im.beta_updates} does nothing with imitation.beta_start 0 {never}")
            changed = [k for k in PPO_UPDATE_ONLY if getattr(self.ppo, k) != getattr(default.ppo, k)]
            if changed:
                idle.append(f"ppo.{', ppo.'.join(changed)} {_do(changed)} nothing under algo dagger (PPO's update; DAgger's are "
                            "imitation.lr, imitation.minibatch_size, imitation.max_grad_norm, imitation.grad_steps)")
        else:
            changed = [f.name for f in dataclasses.fields(ImitationConfig)
                       if getattr(self.imitation, f.name) != getattr(default.imitation, f.name)]
            if changed:
                idle.append(f"imitation.{', imitation.'.join(changed)} {_do(changed)} nothing under algo {self.algo} (DAgger settings)")
        return idle

    @property
    def run_dir(self) -> Path:
        return Path(self.run.runs_dir) / self.name

    def rollout_steps(self) -> int:
        """Decision steps per world per update so that one update sees >= ppo.batch_size transitions."""
        per_step = self.n_envs * self.task.n_pursuers
        return max(1, -(-self.ppo.batch_size // per_step))


def _deep_update(base: Mapping[str, Any], new: Mapping[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for k, v in new.items():
        out[k] = _deep_update(out[k], v) if isinstance(v, Mapping) and isinstance(out.get(k), Mapping) else v
    return out


def _do(names: Sequence[str]) -> str:
    """The verb for a list of settings: 'ppo.lr does', 'ppo.lr, ppo.clip do'."""
    return "does" if len(names) == 1 else "do"


LAYOUT_KEYS = ("task.layout", "layouts", "run.validation_layouts")


def layout_refs(cfg: TrainConfig) -> list[tuple[str, tuple]]:
    """(key, layout references) of each key of LAYOUT_KEYS in `cfg`, in that order."""
    return [("task.layout", (cfg.task.layout,)), ("layouts", tuple(cfg.layouts)),
            ("run.validation_layouts", tuple(cfg.run.validation_layouts))]


def layout_key_sources(overrides: Sequence[str]) -> dict[str, str]:
    """Which '--set KEY=VALUE' gave each layout key (LAYOUT_KEYS) its value: the last that set it."""
    return {key: given for key, given in key_sources_of(overrides).items() if key in LAYOUT_KEYS}


def key_sources_of(overrides: Sequence[str], flags: Mapping[str, str] | None = None) -> dict[str, str]:
    """Which command-line value gave each dotted key (sections too) its value: the last '--set
    KEY=VALUE' of `overrides` that sets it, else `flags[key]` (e.g. {'init_from': '--init-from
    a.pt'}), as --set applies over the flags."""
    sources = dict(flags or {})
    for text in overrides:
        for key in set_keys(text):
            sources[key] = f"--set {text}"
    return sources


def _is_file_ref(ref: Any) -> bool:
    """Whether a layout reference names a file (not a built-in index such as 2 or '2')."""
    return isinstance(ref, (str, Path)) and not str(ref).strip().isdigit()


def _paths_beside(data: dict[str, Any], path: Path, replaced: Collection[str] = ()) -> None:
    """In a train file's (checked) mapping, the task file and layout files named by a path relative
    to the file's folder and not found from the current folder are found there (configio.found_beside).
    A key in `replaced` (dotted, e.g. 'task.evader.model') is left as it is: a later layer gives it
    another value, so a file it named that is gone is no error. The task_file is always found: a
    --set task_file applies its preset over this one's, which still sets the keys it leaves."""
    if "task_file" in data:
        data["task_file"] = found_beside(data["task_file"], path)
    task, run = data.get("task"), data.get("run")
    if isinstance(task, dict) and "layout" in task and "task.layout" not in replaced:
        task["layout"] = found_layout_ref(task["layout"], path, "task.layout")
    if (isinstance(task, dict) and isinstance(task.get("evader"), dict) and "model" in task["evader"]
            and "task.evader.model" not in replaced):
        task["evader"]["model"] = found_code_ref(task["evader"]["model"], path, "task.evader.model")
    if isinstance(data.get("layouts"), list) and "layouts" not in replaced:
        data["layouts"] = [found_layout_ref(r, path, "layouts") for r in data["layouts"]]
    if isinstance(data.get("rewards"), list) and "rewards" not in replaced:
        data["rewards"] = [found_code_ref(r, path, "rewards") for r in data["rewards"]]
    if (isinstance(run, dict) and isinstance(run.get("validation_layouts"), list)
            and "run.validation_layouts" not in replaced):
        run["validation_layouts"] = [found_layout_ref(r, path, "run.validation_layouts") for r in run["validation_layouts"]]


def _resolve_task_file(ref: str, source: str) -> dict[str, Any]:
    try:
        path = preset_or_file(ref, "task")
    except ConfigError as exc:
        raise ConfigError(f"{source}: task_file {exc}") from None
    data = load_task_yaml(path, f"{source}: task_file {ref}")
    check_values(TaskConfig, data, f"{source}: task_file {ref}")  # an error names the task file, not only the train config
    return data


def _with_layer(merged: Mapping[str, Any], layer: Mapping[str, Any], source: str) -> dict[str, Any]:
    """`merged` with one more layer of settings over it (a train file, or `--set task_file=X`):
    the layer's task_file preset over the task keys so far, then the layer's own keys."""
    ref = layer.get("task_file")
    if ref:
        if not isinstance(ref, str):
            raise ConfigError(f"{key_where(source, 'task_file')}: expected a string, got {ref!r}")
        task = layer.get("task")
        if task is not None and not isinstance(task, Mapping):
            raise ConfigError(f"{key_where(source, 'task')}: expected a mapping, got {task!r}")
        merged = _deep_update(merged, {"task": _resolve_task_file(ref, source)})
    # an empty task: section (beside a task_file, say) leaves the task as it is
    return _deep_update(merged, {k: v for k, v in layer.items() if not (k == "task" and v is None)})


def load_train_config(
    files: Sequence[str | Path] = (),
    overrides: Sequence[str] = (),
    flags: Mapping[str, Any] | None = None,
    flags_source: str = "command-line flag",
    replaced: Collection[str] = (),
) -> TrainConfig:
    """Defaults <- YAML files (a bare name like 'classic' means configs/train/classic.yaml) <- flags <- --set.

    `files` and `overrides` are lists; a single string is taken as a list of one.
    `flags` is a nested mapping (e.g. {"total_steps": 10000, "task": {"fidelity": "point"}});
    `flags_source` names them in errors (a CLI passes what was typed, e.g. '--seed -1').
    `replaced`: dotted keys a caller sets itself after this (render's --set for the -mc run's task):
    the files named there by the YAML files are not looked up, as for keys that `overrides` and
    `flags` set.
    """
    files = [files] if isinstance(files, (str, Path)) else files
    overrides = [overrides] if isinstance(overrides, str) else overrides
    for what, given in (("files", files), ("overrides", overrides)):
        if not isinstance(given, Sequence):
            raise ConfigError(f"load_train_config {what}: expected a list, got {given!r}")
    merged: dict[str, Any] = {}
    source = "defaults"
    replaced = set(replaced) | dotted_keys(flags or {})
    for text in overrides:
        replaced |= set_keys(text)
    for f in files:
        p = preset_or_file(f, "train")
        data = load_yaml(p)
        refuse_another_kind(data, str(p), "train")
        if not data:
            raise ConfigError(f"{p}: the file is empty; a train config sets at least its regime or name "
                              f"(see configs/train/*.yaml), and none at all means the defaults: leave out --config")
        # each file's keys and values checked as read, so an error names the file that holds the bad one
        # (an empty task: section beside a task_file is left to _with_layer)
        check_values(TrainConfig, {k: v for k, v in data.items() if not (k == "task" and v is None)}, str(p))
        _paths_beside(data, p, replaced)
        merged = _with_layer(merged, data, str(p))
        source = str(p)
    rest = []
    for text in overrides:  # a task_file override applies its preset over the files, under the other --set keys
        path, value = parse_override(text, f"--set {text}")
        if path == ["task_file"]:
            source = f"--set {text}"
            merged = _with_layer(merged, {"task_file": value}, source)
        else:
            rest.append(text)
    # the checks across keys judge the files, flags and --set together: a later one may complete an
    # earlier one (a file's regime fine_tune, --init-from CKPT)
    return load(TrainConfig, (), rest, extra=flags, extra_source=flags_source, base=merged, base_source=source)


def set_keys(text: str, prefix: str = "") -> set[str]:
    """The dotted keys a --set KEY=VALUE gives a value, each under `prefix`: KEY and its sections,
    and with a mapping VALUE (which updates KEY's section) every key in it, so 'task={layout: 2}'
    sets 'task.layout'; none when it does not parse (the loader names it later)."""
    try:
        path, value = parse_override(text, f"--set {text}")
    except ConfigError:
        return set()
    return dotted_keys(merge({}, path, value), prefix)


def dotted_keys(mapping: Mapping[str, Any], prefix: str = "") -> set[str]:
    """Every key of a nested mapping as a dotted path, sections included ('task', 'task.layout')."""
    keys: set[str] = set()
    for key, value in mapping.items():
        keys.add(prefix + str(key))
        if isinstance(value, Mapping):
            keys |= dotted_keys(value, f"{prefix}{key}.")
    return keys


def train_config_from_dict(data: Mapping[str, Any], source: str) -> TrainConfig:
    """Rebuild a config stored in a checkpoint (a plain dict); keys it lacks take today's defaults
    (`defaults_filled_in` names them)."""
    return build(TrainConfig, _ignored_layout_index_dropped(data), source)


def _ignored_layout_index_dropped(data: Mapping[str, Any]) -> Mapping[str, Any]:
    """`data` with task.layout set to 0 where task.random_layout made it idle: versions before
    2026-12-06 wrote such configs, which today's check refuses as input, and a user cannot edit
    a checkpoint to resume it (the run drew its layouts per episode either way)."""
    task = data.get("task") if isinstance(data, Mapping) else None
    if not (isinstance(task, Mapping) and task.get("random_layout") is True):
        return data
    layout = task.get("layout")
    if isinstance(layout, bool) or not isinstance(layout, int) or layout == 0:
        return data
    return {**data, "task": {**task, "layout": 0}}


def defaults_filled_in(data: Mapping[str, Any], cfg: TrainConfig) -> list[str]:
    """Dotted keys of `cfg` that the stored dict `data` it was built from lacks (a checkpoint written
    before those settings existed): a whole missing section is one entry, `imitation`, not its keys."""
    missing: list[str] = []

    def walk(stored: Mapping[str, Any], full: Mapping[str, Any], prefix: str) -> None:
        for key, value in full.items():
            if key not in stored:
                missing.append(prefix + key)
            elif isinstance(value, dict) and isinstance(stored[key], Mapping):
                walk(stored[key], value, f"{prefix}{key}.")

    walk(data, to_dict(cfg), "")
    return missing


__all__ = ["PPOConfig", "ImitationConfig", "ResidualConfig", "NetConfig", "RunConfig", "TrainConfig", "load_train_config", "train_config_from_dict", "defaults_filled_in", "set_keys", "dotted_keys", "REGIMES"]
