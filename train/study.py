"""The reference experiment in one call: train the regimes on layout 0, evaluate all on 0-3.

Order: full_obs, then fine_tune from its best checkpoint, classic, MAPPO (the reference
study's four), then this project's recipes: imitate (DAgger from the heuristic team),
imitate_ppo (PPO from its best checkpoint), residual (PPO learning a correction added to
the heuristic team), belief (DAgger of a network fed belief features) and belief_ppo (PPO
from it); the heuristic team is evaluated beside them.
A short probe of the heuristic first measures how long an evaluation episode takes, so the
whole evaluation is reserved out of the budget (with fewer episodes than asked if it would
not fit) before any training starts. The heuristic team's full evaluation, timed, then sets
the reserve for the arms' evaluations; the rest is training time, handed out arm by arm by
their shares in ARMS of what is left (so an arm that ran over takes from the later ones, not
from the budget). Each arm is evaluated as soon as it has trained, so an evaluation that takes
more or less than its reserve moves the later arms' training time too. Each run stops at its
max_minutes, its learning rate decaying over it, and that time is its share less its closing
validation (fewer validation episodes when they would take more than VALIDATION_SHARE of it),
priced at the time limit, where a barely trained policy's episodes end, from a probe of the
heuristic team on a few of the arm's own validation episodes (its training fidelity and
layouts, which the evaluation's may not be) and the arm's cost of acting (Arm.eval_cost). A
budget whose plan leaves any arm under MIN_ARM_TRAIN_S is refused with one that would do. All
policies are evaluated on the same task (the reference preset unless told otherwise) with
partial observability: full_obs is trained with full observability but judged like the rest.

An interrupted study continues with `resume=True` (`study --resume`): arms recorded as
finished in <out>/study.json are kept, the interrupted one resumes from its last.pt with its
share of the new budget added, and the rest train as before. Evaluated cells (one policy on
one layout) are kept in study.json as each ends and played again only when they no longer
match (train/study_evaluation.py).

Outputs in <out>/: runs/<arm>/ (checkpoints, metrics), study.json (the finished arms and evaluated cells), table.txt (the table, then every arm
paired with the heuristic team on the same episodes, pursuit_mj.comparison), table.csv,
table.json (rows, and the pairs under "paired"), plots/*.png, timings.json.
"""

from __future__ import annotations

import dataclasses
import json
import math
import re
import time
from pathlib import Path
from typing import Callable, Sequence

from pursuit_mj.config import TaskConfig
from pursuit_mj.configio import TaskValueError, first_difference, parse_override, to_dict
from pursuit_mj.comparison import paired_report, pairs_to_dicts
from pursuit_mj.evader_models import evader_model_sha256
from pursuit_mj.evaluation import (evaluate, format_table, layout_identity, layout_label, plot_rows, table_heading, write_csv,
                                   write_json)
from pursuit_mj.io_utils import atomic_write_text, check_writable_folder, file_sha256, no_new_empty_folders
from pursuit_mj.layout import resolve_layout_ref
from pursuit_mj.obs_spec import ObsSpec
from pursuit_mj.policies import make_policy
from pursuit_mj.provenance import provenance

from .checkpoint import is_training_checkpoint, load_checkpoint
from .config import load_train_config, set_keys, train_config_from_dict
from .policy import load_policy
from .study_evaluation import HEURISTIC, KeptEvaluation
from .folder_lock import lock_folder, release_lock
from .trainer import Trainer
from .validation import FixedSeedValidator

@dataclasses.dataclass(frozen=True)
class Arm:
    """One trained policy of the study: its name, its config preset, its share of the training
    budget, and the arm whose best checkpoint it starts from (None: from scratch)."""

    name: str
    config: str
    share: float
    start_from: str | None = None
    eval_cost: float = 1.0  # its evaluation's time over the heuristic team's on the same episodes (measured)


#: the trained arms, in training order; shares sum to 1
ARMS = (
    Arm("full_obs", "full_obs", 0.14, eval_cost=1.1),
    Arm("fine_tune", "fine_tune", 0.1, start_from="full_obs"),
    Arm("classic", "classic", 0.12, eval_cost=1.1),
    Arm("mappo", "mappo", 0.12, eval_cost=1.3),
    Arm("imitate", "imitate", 0.08),
    Arm("imitate_ppo", "finetune_ppo", 0.1, start_from="imitate"),
    Arm("residual", "residual", 0.08, eval_cost=1.4),  # the network and the heuristic team it corrects
    Arm("belief", "belief", 0.12, eval_cost=2.1),  # belief features: the team's memory, built every step
    Arm("belief_ppo", "belief_ppo", 0.14, start_from="belief", eval_cost=2.1),
)
#: sum of the arms' evaluation times in units of the heuristic team's
ARMS_EVAL_COST = sum(a.eval_cost for a in ARMS)
ARM_START_S = 3.0  # s an arm spends outside its max_minutes besides its validation: building worlds, loading
MIN_TRAIN_MINUTES = 0.01  # below this the arms would not train at all
FEW_EPISODES = 20  # fewer per layout than this and the study says its table is rough
MIN_TRAIN_FRACTION = 0.4  # evaluation may take at most the rest of the budget
VALIDATION_SHARE = 0.3  # at most this part of an arm's time goes to its closing validation
MIN_VALIDATION_EPISODES = 4
MIN_ARM_TRAIN_S = 10.0  # s: a budget planned to leave an arm less is refused; an arm left less by overruns is warned


@dataclasses.dataclass(frozen=True)
class StudyPlan:
    budget_minutes: float
    out: Path
    eval_task: TaskConfig
    layouts: tuple[int | str, ...] = (0, 1, 2, 3)
    episodes: int = 150
    worlds: int = 32
    seed: int = 0
    train_overrides: tuple[str, ...] = ()
    resume: bool = False  # continue the study in `out`: keep its finished arms, resume its interrupted one
    eval_task_name: str = ""  # how table.txt's heading names eval_task ('task hard', pursuit_cli.common.task_named); '' for nothing


STATE_FILE = "study.json"  # in <out>/: the arms trained and cells evaluated so far, written as each ends


def _load_state(plan: StudyPlan) -> dict:
    """The study's record of finished arms: new (and written) for a fresh study, read for --resume;
    ValueError when there is nothing to continue or it was trained with other --train-set values."""
    path = plan.out / STATE_FILE
    if not plan.resume:
        state = {"train_overrides": list(plan.train_overrides), "arms": {}}
        _save_state(plan, state)
        return state
    runs = plan.out / "runs"
    lost = (f"; its trained runs in {runs} cannot be resumed without it: move {runs} aside (its best.pt files stay "
            f"usable with eval --model) and run the study again without --resume") if runs.is_dir() else ""
    if not path.is_file():
        raise ValueError(f"--resume: {plan.out} holds no study to continue (no {STATE_FILE}){lost}")
    try:
        state = json.loads(path.read_text())
        arms, stored = dict(state["arms"]), list(state["train_overrides"])
        if not all(isinstance(text, str) for text in stored):
            raise TypeError("its train_overrides are not all KEY=VALUE strings")
    except (ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"--resume: {path} is not a study record ({exc}){lost}") from None
    changed = _changed_settings(stored, plan.train_overrides, f"{path}, \"train_overrides\" {{text!r}}")
    then, now = _arm_configs(stored), _arm_configs(plan.train_overrides)
    if then is not None and now is not None:  # the configs decide where both load
        if then == now:
            changed = []  # spelled otherwise (a default given, a key given twice), trained alike
        elif not changed:
            changed = [_config_difference(then, now)]  # the same keys, which in another order set otherwise
    if changed:
        raise ValueError(f"--resume: the study in {plan.out} was trained with other settings: {'; '.join(changed)}. "
                         f"Give the same --train-fidelity and --train-set values as its first session (in any order)")
    for arm in ARMS:  # checked now, not at the evaluation after every other arm has trained
        if arm.name in arms:
            try:
                load_checkpoint(plan.out / "runs" / arm.name / "best.pt")
            except ValueError as exc:
                raise ValueError(f"--resume: the {arm.name} arm is kept as finished in {path}, but {exc}; delete its "
                                 f"entry under \"arms\" there and its run folder {plan.out / 'runs' / arm.name} to train "
                                 f"it again") from None
    kept = {key: state[key] for key in ("evaluation", "seconds", "budgets") if key in state}
    # the evaluation is checked by KeptEvaluation, the seconds and budgets by _run_study
    return {"train_overrides": stored, "arms": arms, **kept}


def kept_cells(out: Path) -> int:
    """How many evaluated cells (one policy on one layout) <out>/study.json keeps: what a fresh
    study there would throw away (0 when it holds none or is no study record)."""
    try:
        cells = json.loads((Path(out) / STATE_FILE).read_text())["evaluation"]["cells"]
        return sum(len(by_layout) for by_layout in cells.values() if isinstance(by_layout, dict))
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return 0


def _minutes(seconds: float) -> float:
    return seconds / 60.0


def _rounded_up(minutes: float) -> str:
    """A budget that would do, rounded up: to 0.1 min below 10 min (a resumed study's last run
    needs seconds, which whole minutes showed as 'about 0 min'), else to whole minutes."""
    return f"{math.ceil(minutes * 10) / 10:.1f}" if minutes < 10 else f"{math.ceil(minutes)}"


def _runs(n: int) -> str:
    return _count(n, "run")


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}{'s' if n != 1 else ''}"


def _duration(seconds: float) -> str:
    """'42 s' below two minutes, else '3.5 min'."""
    return f"{seconds:.0f} s" if seconds < 120 else f"{seconds / 60.0:.1f} min"


BATCH_FLOOR = 1.0  # part of a batch's time that fewer episodes do not save: all of it, to be safe (measured on
#                    two idle runs: 1 episode per layout took 0.38 of the 8-episode probe's time, 6 episodes 1.28)


def eval_seconds(probe_s: float, probe_episodes: int, episodes: int) -> float:
    """Seconds to evaluate the heuristic team with `episodes` per layout, from a probe of
    `probe_episodes` per layout (run in parallel worlds) that took `probe_s`: proportional beyond
    the probe; below it, BATCH_FLOOR of the probe's time stays (a batch of parallel episodes
    lasts as long as its longest, and a step of few worlds costs nearly as much as of many)."""
    fraction = episodes / probe_episodes
    return probe_s * (fraction if fraction >= 1.0 else BATCH_FLOOR + (1.0 - BATCH_FLOOR) * fraction)


def probe_seed(seed: int) -> int:
    """The table seed of the evaluation speed probe: the next after the study's `seed` (so that it
    plays other episodes than the table), 0 after the largest seed, 2**63 - 1."""
    return (seed + 1) % 2**63


def fit_episodes(plan: StudyPlan, probe_s: float, probe_episodes: int, spent_s: float,
                 arms_to_train: int = len(ARMS)) -> tuple[int, float]:
    """(episodes per policy and layout, minutes left for training) within the budget.

    The heuristic and the trained policies are evaluated with the same number of episodes;
    it shrinks from plan.episodes when evaluation would take more than its share (all of the
    budget when no arm is left to train).
    """
    total_s = plan.budget_minutes * 60.0
    rounds = 1 + ARMS_EVAL_COST  # the team's evaluation and the arms'
    cap = total_s * (1.0 - (MIN_TRAIN_FRACTION if arms_to_train else 0.0)) - spent_s
    episodes = plan.episodes
    while episodes > 1 and rounds * eval_seconds(probe_s, probe_episodes, episodes) > cap:
        episodes = max(1, min(episodes - 1, int(episodes * cap / (rounds * eval_seconds(probe_s, probe_episodes, episodes)))))
    evaluation_s = rounds * eval_seconds(probe_s, probe_episodes, episodes)
    return episodes, _minutes(total_s - spent_s - evaluation_s - ARM_START_S * arms_to_train)


def timeout_episode_seconds(seconds_per_episode: float, team_steps: float, max_steps: int) -> float:
    """Seconds of an episode played to the time limit of `max_steps` decision steps, from the team's
    `seconds_per_episode` over episodes of `team_steps` mean steps: a barely trained policy's
    validation episodes end there, not at the team's length (a 4-episode validation priced at the
    team's length took 16 s for the 3.5 planned)."""
    return seconds_per_episode * max(max_steps / max(team_steps, 1.0), 1.0)


def arm_budget(left_s: float, share: float, shares_left: float, validation_episodes: int,
               policy_episode_s: float, team_episode_s: float) -> tuple[float, int]:
    """(max_minutes, validation episodes) of the next arm.

    Its time is `share` / `shares_left` of the `left_s` training seconds still unspent. The run
    ends with a validation outside max_minutes: `validation_episodes` episodes, each costing
    `policy_episode_s` (priced at the time limit, `timeout_episode_seconds`) plus `team_episode_s`
    when the heuristic team plays them too (0 when it does not). That is reserved out of its
    time, with fewer episodes when they would take more than VALIDATION_SHARE of it.
    """
    arm_s = max(left_s, 0.0) * share / shares_left
    per_episode = policy_episode_s + team_episode_s
    fits = int(VALIDATION_SHARE * arm_s / max(per_episode, 1e-9))
    episodes = min(validation_episodes, max(MIN_VALIDATION_EPISODES, fits))
    return max(arm_s - episodes * per_episode, 0.0) / 60.0, episodes


@dataclasses.dataclass(frozen=True)
class ValidationSpeed:
    """How fast the heuristic team plays an arm's validation episodes (in its training task, on its
    validation layouts), by a probe: seconds per episode and mean decision steps per episode."""

    team_episode_s: float
    team_steps: float


VALIDATION_PROBE_EPISODES = 8  # a validation plays all its episodes at once; a probe of fewer worlds costs
#                                more per episode, so this prices a validation of up to 24 episodes from above


def _validation_probe_setup(cfg) -> tuple[TaskConfig, tuple, int, int]:
    """(task, layouts, episodes, seed) of a probe of `cfg`'s validation, as the trainer builds it."""
    r = cfg.run
    layouts = tuple(r.validation_layouts or cfg.layouts)
    # at least a world per layout (world w plays layouts[w % len]; PursuitEnv refuses a layout no world plays)
    return cfg.task, layouts, min(r.validation_episodes, max(VALIDATION_PROBE_EPISODES, len(layouts))), r.validation_seed


def probe_validation_speed(cfg) -> ValidationSpeed:
    """Time the heuristic team on a few of `cfg`'s validation episodes (the trainer's FixedSeedValidator,
    its worlds built outside the timing)."""
    task, layouts, episodes, seed = _validation_probe_setup(cfg)
    validator = FixedSeedValidator(task, list(layouts) or None, episodes, seed, cfg.run.sim_threads)
    team = make_policy("heuristic", task)
    t0 = time.perf_counter()
    _, records = validator.run(team)
    seconds = time.perf_counter() - t0
    return ValidationSpeed(seconds / episodes, sum(r.steps for r in records) / len(records))


@dataclasses.dataclass(frozen=True)
class ArmValidation:
    """What an arm's closing validation costs: its time limit (decision steps), its episode count,
    whether the heuristic team plays the same episodes, the arm's acting time over the team's
    (Arm.eval_cost) and how fast the team plays them (probed in the arm's own training task)."""

    max_steps: int
    episodes: int
    vs_heuristic: bool
    speed: ValidationSpeed
    policy_cost: float = 1.0

    @classmethod
    def of(cls, cfg, speed: ValidationSpeed, policy_cost: float = 1.0) -> "ArmValidation":
        return cls(cfg.task.max_steps, cfg.run.validation_episodes, cfg.run.validation_vs_heuristic, speed, policy_cost)

    def budget(self, left_s: float, share: float, shares_left: float) -> tuple[float, int]:
        """arm_budget for this arm, its policy's episodes priced at its time limit."""
        team_s = self.speed.team_episode_s
        return arm_budget(left_s, share, shares_left, self.episodes,
                          self.policy_cost * timeout_episode_seconds(team_s, self.speed.team_steps, self.max_steps),
                          team_s if self.vs_heuristic else 0.0)


def arm_validations(plan: "StudyPlan", arms: Sequence[Arm]) -> dict[str, ArmValidation]:
    """{arm name: ArmValidation} of `arms`, the team probed once per distinct validation setup
    (fidelity, observability and layouts differ between arms; the reward scales do not matter)."""
    speeds: dict[tuple, ValidationSpeed] = {}
    validations = {}
    for arm in arms:
        cfg = load_train_config([arm.config], _arm_overrides(plan, arm))
        task, layouts, episodes, seed = _validation_probe_setup(cfg)
        key = (task.fidelity, task.observability, layouts, episodes, seed, task.max_steps, task.n_pursuers, task.n_evaders)
        if key not in speeds:
            speeds[key] = probe_validation_speed(cfg)
        validations[arm.name] = ArmValidation.of(cfg, speeds[key], arm.eval_cost)
    return validations


def planned_training_seconds(train_s: float, arms: Sequence[Arm], validations: dict[str, ArmValidation]) -> dict[str, float]:
    """{arm name: seconds of training} when `train_s` seconds are handed to `arms` by their shares
    and every arm takes just its time (each then gets its share of the whole)."""
    shares = sum(a.share for a in arms)
    return {a.name: 60.0 * validations[a.name].budget(train_s, a.share, shares)[0]
            for a in arms}


def training_seconds_needed(arms: Sequence[Arm], validations: dict[str, ArmValidation]) -> float:
    """The fewest training seconds, all arms together, that leave each of `arms` MIN_ARM_TRAIN_S
    beside its closing validation (to within 1 %)."""
    need = MIN_ARM_TRAIN_S
    while min(planned_training_seconds(need, arms, validations).values()) < MIN_ARM_TRAIN_S:
        need *= 1.01
    return need


def short_arm_warning(regime: str, seconds: float) -> str:
    """What the study says of an arm left under MIN_ARM_TRAIN_S of training."""
    return (f"[study] warning: {regime} is left {seconds:.0f} s of training, too little to learn anything (the runs and "
            f"evaluations before took longer than planned, as when a policy plays its episodes to the time limit); "
            f"its row in the table is of a nearly untrained policy, and the study may run over its budget. A larger "
            f"--budget-minutes gives every run time to learn")


#: train keys the study sets for each arm itself, and why (a --train-set of them is refused)
STUDY_SETS = {"name": "its run goes to <out>/runs/<arm>", "run.runs_dir": "its run goes to <out>/runs/<arm>",
              "max_minutes": "its share of the budget", "init_from": "the best.pt of the arm it continues"}


def check_train_overrides(plan: StudyPlan) -> None:
    """Every arm's config with plan.train_overrides, its layouts and reward terms loaded, before anything runs: ValueError
    naming the --train-set value refused and the arms that refuse it (found at an arm's start, it cost the earlier
    arms' time; _train_set_refusal), a key the study sets for each arm (STUDY_SETS), or an arm that trains with other
    range readings than the evaluation task gives (`_check_rays`)."""
    for text in plan.train_overrides:
        parse_override(text, f"--train-set {text}")  # one that does not parse is named as --train-set
        for key in STUDY_SETS:  # set_keys: 'run={runs_dir: x}' sets run.runs_dir as 'run.runs_dir=x' does
            if key in set_keys(text):
                raise ValueError(f"--train-set {text}: the study sets {key} for each arm ({STUDY_SETS[key]}); leave it out")
    configs, refused = {}, {}
    for arm in ARMS:
        # an arm that continues another starts from that one's best.pt, which the study gives it as it starts
        start = [f"init_from={_start_checkpoint(plan, arm)}"] if arm.start_from else []
        try:
            cfg = load_train_config([arm.config], ["name=check", "total_steps=1000000000", "task.layout=0",
                                                   *plan.train_overrides, *start])
            anchorless = _anchor_without_a_start(cfg, plan)
            if anchorless:  # the config's own advice, 'set --init-from', is the train command's
                refused[arm] = anchorless
                continue
            cfg.check_complete()
            cfg.check_layouts()  # found at the arm's start, after the team's evaluation was kept in study.json
            cfg.check_code()  # likewise
        except ValueError as exc:
            refused[arm] = _as_train_set(str(exc), plan.train_overrides)
            continue
        configs[arm] = cfg
    if refused:
        raise ValueError(_train_set_refusal(refused, plan.train_overrides))
    _check_rays(plan, configs)


def _start_checkpoint(plan: StudyPlan, arm: Arm) -> Path:
    """The checkpoint an arm that continues another starts from: that arm's best.pt."""
    return plan.out / "runs" / arm.start_from / "best.pt"


def _anchor_without_a_start(cfg, plan: StudyPlan) -> str | None:
    """Why an arm trained from scratch cannot take the ppo.anchor_coef a --train-set gives it (the
    anchor is the actor a run starts from), with advice a study's user can follow: the train
    config's, 'set --init-from', is refused in a study. None when the arm takes it."""
    if cfg.algo == "dagger" or cfg.ppo.anchor_coef <= 0 or cfg.init_from:
        return None
    starting = [a for a in ARMS if a.start_from]
    names = ", ".join(a.name for a in starting[:-1]) + f" and {starting[-1].name}"
    example = starting[0]
    coef = f"{cfg.ppo.anchor_coef:g}"
    return (f"train config: ppo.anchor_coef {coef} needs a start to anchor to (the actor a run starts from), and these arms "
            f"train from scratch: a study starts only {names} from a checkpoint (the best.pt of the arm each continues), "
            f"and --train-set gives every arm the value; leave it out, or train one such run with it on its own: "
            f"pursuit-mj train --config {example.config} --init-from {_start_checkpoint(plan, example)} "
            f"--set ppo.anchor_coef={coef}")


def _as_train_set(said: str, overrides: Sequence[str]) -> str:
    """An arm's refusal, with the overrides it names as --set (its config's flag) named as the user typed them."""
    for text in overrides:
        key = text.split("=", 1)[0].strip()
        said = said.replace(f"--set {text}", f"--train-set {text}")
        said = said.replace(f"--set '{key}=", f"--train-set '{key}=")  # the quoting advised (configio.quoted_override)
    return said


def _refused_override(said: str, overrides: Sequence[str]) -> str | None:
    """The override an arm's refusal `said` is about: the one it names as '--train-set TEXT', else the
    last whose key it names as a word (a config check names 'task.layout nope.yaml', not the flag);
    None when it names none."""
    for text in overrides:
        if f"--train-set {text}" in said:
            return text
    named = [text for text in overrides
             if re.search(r"(?<![\w.])" + re.escape(text.split("=", 1)[0].strip()) + r"(?![\w])", said)]
    return named[-1] if named else None


def _train_set_refusal(refused: dict[Arm, str], overrides: Sequence[str]) -> str:
    """One line for the arms that refuse the --train-set values (arm -> its refusal, as --train-set): for
    each value refused (in arm order), '--train-set TEXT: the a and b arms refuse it (a config): WHY', or
    'every arm refuses it', with the config named where the arms' refusals differ; joined by '; '."""
    by_value: dict[str | None, dict[Arm, str]] = {}
    for arm, said in refused.items():
        by_value.setdefault(_refused_override(said, overrides), {})[arm] = said
    return "; ".join(_value_refusal(text, arms_said, overrides) for text, arms_said in by_value.items())


def _value_refusal(text: str | None, refused: dict[Arm, str], overrides: Sequence[str]) -> str:
    """'--train-set TEXT: the a and b arms refuse it (a config): WHY' for the arms that refuse the
    override `text` (None: one their refusals do not name), see _train_set_refusal."""
    arms = list(refused)
    first = refused[arms[0]]
    flag = f"--train-set {text}" if text is not None else f"--train-set ({', '.join(overrides)})"
    why = first.removeprefix(f"{flag}: ").removeprefix("train config: ")
    if len(arms) == len(ARMS):
        who = "every arm refuses it"
    else:
        names = [a.name for a in arms]
        listed = names[0] if len(names) == 1 else f"{', '.join(names[:-1])} and {names[-1]}"
        who = f"the {listed} arm{'s refuse' if len(names) > 1 else ' refuses'} it"
    if len(arms) < len(ARMS) or len(set(refused.values())) > 1:
        who += f" ({arms[0].config} config)"
    return f"{flag}: {who}: {why}"


def _check_rays(plan: StudyPlan, configs: dict[Arm, object]) -> None:
    """TaskValueError (key n_rays, so that the CLI names the flag that gave the count) unless every arm
    (its train config in `configs`) trains with as many range readings as the evaluation task gives: its
    policy reads the rays it learned with, and the evaluation after its training refused it ('observation
    spec does not match'), the team's evaluation and the arm's training time spent. The value named is the
    arms' when a --train-set sets task.n_rays, else the evaluation task's."""
    judged = plan.eval_task.n_rays
    differ = [arm for arm, cfg in configs.items() if cfg.task.n_rays != judged]
    if not differ:
        return
    trained = configs[differ[0]].task.n_rays
    names = [arm.name for arm in differ]
    who = "every arm trains" if len(differ) == len(ARMS) else (
        f"the {names[0]} arm trains" if len(names) == 1 else f"the {', '.join(names[:-1])} and {names[-1]} arms train")
    reason = (f"the evaluation task gives {judged} range readings (n_rays) and {who} with {trained} ({differ[0].config} "
              f"config with the --train-set values); a trained policy reads the rays it learned with: give both the same "
              f"count (--set n_rays=N and --train-set task.n_rays=N)")
    from_train_set = any("task.n_rays" in set_keys(text) for text in plan.train_overrides)
    raise TaskValueError("n_rays", trained if from_train_set else judged, reason)


def run_study(plan: StudyPlan, log: Callable[[str], None] = print, stop_requested: Callable[[], bool] | None = None) -> dict:
    """Train, evaluate, write the table and charts; returns {'rows', 'timings', 'episodes'}.

    The study holds a lock on plan.out while it runs: a second study there is refused at once
    (FolderInUse), not when it reaches the arm whose run folder the first one holds."""
    check_train_overrides(plan)
    if plan.resume and not plan.out.is_dir():
        raise ValueError(f"--resume: --out {plan.out} is not a folder with a study to continue")
    with no_new_empty_folders():  # refused before it kept anything: no folder of '--out a/b/new' is left
        check_writable_folder(plan.out, f"--out {plan.out}")
        new_lock = not (plan.out / STUDY_LOCK).exists()  # after the folder is made: '--out new/../mine' finds mine/.study.lock
        lock = lock_folder(plan.out, STUDY_LOCK, "study folder", "study", "give another --out")
        try:
            _refuse_an_earlier_study(plan)
            result = _run_study(plan, log, stop_requested)
        except BaseException:  # nor a lock file in a folder that was there ('--resume --out mine' refused)
            release_lock(lock, plan.out / STUDY_LOCK, remove_file=new_lock)
            raise
        lock.close()
        return result


STUDY_LOCK = ".study.lock"  # in <out>/: held by the study running there


def _refuse_an_earlier_study(plan: StudyPlan) -> None:
    """ValueError when a fresh study would train or evaluate over what an earlier one in plan.out made."""
    if plan.resume:
        return
    if any((plan.out / "runs").glob("*/last.pt")):
        raise ValueError(f"--out {plan.out}: already holds study runs; continue them with --resume, or choose another folder")
    cells = kept_cells(plan.out)
    if cells:  # a study stopped during its evaluation before any run: starting afresh would drop what it played
        raise ValueError(f"--out {plan.out}: its {STATE_FILE} keeps {cells} evaluated policy-layout cell{'s' if cells > 1 else ''} "
                         f"of an interrupted study; continue it with --resume, or choose another folder")


def _run_study(plan: StudyPlan, log: Callable[[str], None], stop_requested: Callable[[], bool] | None) -> dict:
    """run_study in a folder it holds. study.json's "seconds" counts the wall time of every session so
    far (to its last record, written as each arm or evaluated cell ends and when the session stops),
    and its "budgets" the --budget-minutes of each of those sessions; a session refused (ValueError)
    before it trained an arm or recorded any arm or cell adds nothing to either."""
    state = _load_state(plan)
    t_start = time.perf_counter()
    earlier_s = _earlier_sessions_seconds(state)
    budgets = [*_earlier_sessions_budgets(state), plan.budget_minutes]  # this session's last
    state.pop("budgets", None)  # recorded with this session's once it has worked
    worked = False  # the session trained or recorded something: its time counts whatever stops it

    def save() -> None:
        nonlocal worked
        worked = True
        state["seconds"] = round(earlier_s + time.perf_counter() - t_start, 1)
        state["budgets"] = budgets
        _save_state(plan, state)

    def training() -> None:
        nonlocal worked
        worked = True

    try:
        result = _run_study_sessions(plan, state, save, t_start, log, stop_requested, training)
    except BaseException as exc:
        # only the time goes to the record on disk: the state in memory may hold an evaluation
        # emptied for a resume that was then refused (another --seed, say), which must not replace the kept one
        if worked or not isinstance(exc, ValueError):
            _save_seconds(plan, round(earlier_s + time.perf_counter() - t_start, 1), budgets)
        elif not plan.resume:  # a fresh study refused before it did anything leaves no record to --resume
            (plan.out / STATE_FILE).unlink(missing_ok=True)
        raise
    if earlier_s > 0:
        result["timings"]["total, all sessions"] = earlier_s + result["timings"]["total"]
        atomic_write_text(plan.out / "timings.json", _timings_json(result["timings"]))
    return result


def _save_seconds(plan: StudyPlan, seconds: float, budgets: list[float]) -> None:
    """Set "seconds" and "budgets" in the study.json on disk, leaving the rest as it is (nothing if it cannot)."""
    try:
        state = json.loads((plan.out / STATE_FILE).read_text())
        if isinstance(state, dict):
            _save_state(plan, {**state, "seconds": seconds, "budgets": budgets})
    except (OSError, ValueError):
        pass


def _earlier_sessions_budgets(state: dict) -> list[float]:
    """The --budget-minutes of the study's earlier sessions by its record ([] if none or unreadable)."""
    budgets = state.get("budgets", [])
    ok = isinstance(budgets, list) and all(
        isinstance(b, (int, float)) and not isinstance(b, bool) and math.isfinite(b) and b > 0 for b in budgets)
    return [float(b) for b in budgets] if ok else []


def _earlier_sessions_seconds(state: dict) -> float:
    """Wall seconds of the study's earlier sessions by its record (0 if none or unreadable)."""
    seconds = state.get("seconds", 0.0)
    ok = isinstance(seconds, (int, float)) and not isinstance(seconds, bool) and math.isfinite(seconds) and seconds >= 0
    return float(seconds) if ok else 0.0


def _run_study_sessions(plan: StudyPlan, state: dict, save: Callable[[], None], t_start: float,
                        log: Callable[[str], None], stop_requested: Callable[[], bool] | None,
                        training: Callable[[], None]) -> dict:
    """Plan, train and evaluate what `state` does not hold yet; `save` writes study.json, `training`
    is called as an arm's training starts (the session is past its refusals)."""
    todo = [arm for arm in ARMS if arm.name not in state["arms"]]
    timings: dict[str, float] = {}

    heuristic = make_policy("heuristic", plan.eval_task)
    validations: dict[str, ArmValidation] = {}
    if todo:  # the arms' closing validations are priced in their own training task
        t0 = time.perf_counter()
        validations = arm_validations(plan, todo)
        timings["validation speed probe"] = time.perf_counter() - t0
    kept = KeptEvaluation(plan, state, save, log)
    planned = None  # (seconds planned for the team's evaluation, for training) by a fresh plan
    if kept.episodes is None:
        t0 = time.perf_counter()
        probe = max(2, min(plan.worlds, plan.episodes) // len(plan.layouts))  # per layout: they differ in length
        evaluate(heuristic, plan.eval_task, list(plan.layouts), probe, probe_seed(plan.seed), plan.worlds, label="heuristic")
        timings["evaluation speed probe"] = time.perf_counter() - t0
        episodes, train_minutes = fit_episodes(plan, timings["evaluation speed probe"], probe, time.perf_counter() - t_start,
                                               len(todo))

        def fresh_needed() -> float:
            return _fresh_budget_needed(plan, todo, validations, timings["evaluation speed probe"], probe,
                                        time.perf_counter() - t_start)

        if todo and train_minutes < MIN_TRAIN_MINUTES:
            needed = max(plan.budget_minutes + MIN_TRAIN_MINUTES - train_minutes, fresh_needed())
            raise ValueError(f"--budget-minutes {plan.budget_minutes}: too small on this machine; evaluating {len(ARMS) + 1} "
                             f"policies and starting {_runs(len(todo))} leave {max(train_minutes, 0.0) * 60:.0f} s for training "
                             f"(raise the budget to about {_rounded_up(needed)} min)")
        if todo:
            _refuse_short_arms(plan, todo, validations, train_minutes * 60.0, fresh_needed)
        kept.start(episodes)
        planned = (eval_seconds(timings["evaluation speed probe"], probe, episodes), train_minutes * 60.0)
        log(f"[study] {_count(episodes, 'episode')} per policy and layout" + (f"; {_duration(train_minutes * 60)} left for training" if todo else ""))
        if episodes < min(plan.episodes, FEW_EPISODES):
            log(f"[study] warning: {episodes} episodes per layout give wide intervals (a single episode decides "
                f"{100 / episodes:.0f} points of success); a larger budget buys more")
    else:
        episodes = kept.episodes
        log(f"[study] {_count(episodes, 'episode')} per policy and layout, as the earlier session chose")
    rows, played_s = _evaluate_cells(kept, HEURISTIC, heuristic, "heuristic", plan, episodes, log)
    _time_cells(timings, "heuristic", played_s, kept.seconds(HEURISTIC))
    heuristic_s = kept.seconds(HEURISTIC)  # the whole team's evaluation, in whichever session it was played
    # arms whose cells are all kept (played from the best.pt they have now) cost no more evaluation
    to_evaluate = {arm.name: arm.eval_cost for arm in ARMS
                   if not (arm.name in state["arms"] and kept.covers(arm.name, plan.out / "runs" / arm.name / "best.pt"))}

    def train_end() -> float:
        """When training must end for the evaluations still to come to fit the budget (each arm is
        evaluated as soon as it is trained, so what one takes more or less moves the later arms' time)."""
        return t_start + plan.budget_minutes * 60.0 - sum(to_evaluate.values()) * heuristic_s

    left_s = train_end() - time.perf_counter() - ARM_START_S * len(todo)
    if planned is None and todo:  # a fresh plan checked these before any evaluation
        need_s = max(training_seconds_needed(todo, validations), MIN_TRAIN_MINUTES * 60.0)
        if left_s < MIN_TRAIN_MINUTES * 60.0:
            raise ValueError(f"--budget-minutes {plan.budget_minutes}: too small on this machine; evaluating what is left "
                             f"and starting {_runs(len(todo))} leave {max(left_s, 0.0):.0f} s for training (raise the budget "
                             f"to about {_rounded_up(plan.budget_minutes + (need_s - left_s) / 60.0)} min)")
        _refuse_short_arms(plan, todo, validations, left_s, lambda: plan.budget_minutes + (need_s - left_s) / 60.0)
    if planned is not None and left_s < 0.5 * planned[1]:
        log(f"[study] warning: the heuristic team's evaluation took {played_s:.0f} s where {planned[0]:.0f} s were "
            f"planned (is the machine busy?); {_duration(max(left_s, 0.0))} are left for training, and the study may "
            f"run over its budget")

    t = plan.eval_task
    spec = ObsSpec.make(t.n_pursuers, t.n_evaders, t.n_rays)
    checkpoints: dict[str, Path] = {}

    def evaluate_arm(regime: str) -> None:
        """Play (or take back) the cells of the arm just trained or kept, from its best.pt."""
        kept.use_checkpoint(regime, checkpoints[regime])  # cells played from another best.pt are dropped
        policy = load_policy(checkpoints[regime], spec, name=regime, task=plan.eval_task)
        label = policy.name  # as eval labels it: NAME+shield behind the shield, NAME@BASE for a correction
        arm_rows, arm_played_s = _evaluate_cells(kept, regime, policy, label, plan, episodes, log)
        rows.extend(arm_rows)
        _time_cells(timings, regime, arm_played_s, kept.seconds(regime))
        to_evaluate.pop(regime, None)

    for arm in ARMS:
        regime = arm.name
        run_dir = plan.out / "runs" / regime
        if regime in state["arms"]:
            checkpoints[regime] = run_dir / "best.pt"
            timings[f"{regime} (train, earlier session)"] = float(state["arms"][regime]["train_seconds"])  # the run's clock
            log(f"[study] {regime}: trained in an earlier session, kept")
            evaluate_arm(regime)
            continue
        overrides = _arm_overrides(plan, arm)
        if arm.start_from:
            overrides.append(f"init_from={checkpoints[arm.start_from]}")
        cfg = load_train_config([arm.config], overrides)
        interrupted = (cfg.run_dir / "last.pt").exists()
        if interrupted and not plan.resume:
            raise ValueError(f"study folder {plan.out}: {cfg.run_dir} already holds a run; choose another --out")
        finished_s = _finished_seconds(cfg.run_dir) if interrupted else None
        if finished_s is not None:  # stopped after the arm ended, before study.json said so: not trained again
            try:
                load_checkpoint(run_dir / "best.pt")
            except ValueError as exc:
                raise ValueError(f"--resume: the {regime} arm finished in an earlier session, but {exc}; delete its run "
                                 f"folder {run_dir} to train it again") from None
            checkpoints[regime] = run_dir / "best.pt"
            timings[f"{regime} (train, earlier session)"] = finished_s
            state["arms"][regime] = {"train_seconds": round(finished_s, 1)}
            save()
            log(f"[study] {regime}: finished in an earlier session (stopped before the study recorded it), kept")
            evaluate_arm(regime)
            continue
        i = todo.index(arm)
        left_s = train_end() - time.perf_counter() - ARM_START_S * (len(todo) - i)  # this and every later arm's start
        minutes, val_episodes = validations[regime].budget(left_s, arm.share, sum(a.share for a in todo[i:]))
        if minutes * 60.0 < MIN_ARM_TRAIN_S:
            log(short_arm_warning(regime, minutes * 60.0))
        if interrupted:  # its own config, with the time it had plus its share of this session's
            trainer = Trainer.resume(cfg.run_dir, log=log, max_minutes=_spent_minutes(cfg.run_dir) + max(minutes, 0.01),
                                     progress=cfg.run.progress, rerun=cfg.run.rerun,
                                     restart=f"delete the arm's run folder {cfg.run_dir} to train the arm afresh in this study")
            log(f"[study] resuming {regime} for {_duration(minutes * 60)} more")
        else:
            cfg = load_train_config([arm.config], overrides + [f"max_minutes={max(minutes, 0.01):.4f}",
                                                              f"run.validation_episodes={val_episodes}"])
            log(f"[study] training {regime} for {_duration(minutes * 60)}, then validating on {val_episodes} episodes "
                f"({cfg.task.fidelity} fidelity)")
            trainer = Trainer(cfg, log=log, earlier_run_advice=(
                f"Go on from its best.pt (copy it over last.pt, then pursuit-mj study --resume), or delete the arm's run "
                f"folder {cfg.run_dir} to train the arm afresh in this study"))
        trainer.resume_command = "pursuit-mj study --resume (the whole study; see below)"
        trainer.diverged_hint = study_diverged_hint
        training()
        result = trainer.train(stop_requested)  # see Trainer.train: a stop signal reported as another error
        if result["status"] != "done":
            raise KeyboardInterrupt
        # the run's own clock (collection, updates, validations), as for arms kept from an earlier session
        train_s = float(result["counters"]["seconds"])
        timings[f"{regime} (train{', all sessions' if interrupted else ''})"] = train_s
        checkpoints[regime] = run_dir / "best.pt"
        state["arms"][regime] = {"train_seconds": round(train_s, 1)}
        save()
        evaluate_arm(regime)
    timings["total"] = time.perf_counter() - t_start
    save()  # the record's seconds and budgets, this session's included, for the table's meta
    _write(plan, rows, timings, episodes, state)
    return {"rows": rows, "timings": timings, "episodes": episodes}


def study_diverged_hint(last: Path | None, update: int, key: str) -> str:
    """What a diverged arm's run folder keeps and how a study takes other settings (Trainer.diverged_hint):
    a new study, as a resume goes on with the settings the study started with."""
    kept = f"{last} keeps update {update}" if last is not None else "no update was saved"
    return (f"{kept}; a study takes other settings as a new one: --train-set {key}=... with another --out (study "
            f"--resume goes on with the settings the study started with)")


def _arm_overrides(plan: StudyPlan, arm: Arm) -> list[str]:
    """The train overrides the study gives `arm` (its init_from aside)."""
    return [f"name={arm.name}", f"run.runs_dir={plan.out / 'runs'}", "total_steps=1000000000", "task.layout=0",
            *plan.train_overrides]


def _fresh_budget_needed(plan: StudyPlan, todo: Sequence[Arm], validations: dict[str, ArmValidation], probe_s: float,
                         probe_episodes: int, spent_s: float) -> float:
    """The smallest budget (min, to within 2 %) whose fresh plan leaves every arm MIN_ARM_TRAIN_S."""
    budget = plan.budget_minutes
    while True:
        budget = budget * 1.02 + 0.01
        trial = dataclasses.replace(plan, budget_minutes=budget)
        episodes, train_minutes = fit_episodes(trial, probe_s, probe_episodes, spent_s, len(todo))
        if min(planned_training_seconds(train_minutes * 60.0, todo, validations).values()) >= MIN_ARM_TRAIN_S:
            return budget


def _refuse_short_arms(plan: StudyPlan, todo: Sequence[Arm], validations: dict[str, ArmValidation], train_s: float,
                       budget_needed: Callable[[], float]) -> None:
    """ValueError naming the arm that `train_s` seconds of training, shared out as planned, leave
    under MIN_ARM_TRAIN_S beside its closing validation, and the budget that would do."""
    planned = planned_training_seconds(train_s, todo, validations)
    name = min(planned, key=planned.get)
    if planned[name] >= MIN_ARM_TRAIN_S:
        return
    v = validations[name]
    raise ValueError(f"--budget-minutes {plan.budget_minutes}: too small on this machine; the {name} arm would be left "
                     f"{max(planned[name], 0.0):.0f} s of training (every run needs at least "
                     f"{MIN_ARM_TRAIN_S:.0f} s to learn anything, beside a closing validation priced at its time limit "
                     f"of {v.max_steps} steps, where a barely trained policy's episodes end) (raise the budget to about "
                     f"{_rounded_up(budget_needed())} min)")


def _evaluate_cells(kept: KeptEvaluation, key: str, policy, label: str, plan: StudyPlan, episodes: int,
                    log: Callable[[str], None]) -> tuple[list, float]:
    """(rows of `policy` on every layout, seconds spent playing them now): a cell kept from an
    earlier session is taken back, any other is played and kept as it ends."""
    rows, played_s, reused = [], 0.0, 0
    for ref in plan.layouts:
        row = kept.row(key, label, ref)
        if row is None:
            t0 = time.perf_counter()
            (row,) = evaluate(policy, plan.eval_task, [ref], episodes, plan.seed, plan.worlds, label=label)
            spent = time.perf_counter() - t0
            played_s += spent
            kept.keep(key, row, spent)
        else:
            reused += 1
        rows.append(row)
    if reused:
        log(f"[study] {label}: {reused} of {_count(len(plan.layouts), 'layout')} evaluated in an earlier session, kept")
    return rows, played_s


def _time_cells(timings: dict[str, float], name: str, played_s: float, kept_s: float) -> None:
    """The evaluation time of one policy: played now, and what its kept cells took before."""
    if played_s > 0:
        timings[f"{name} (eval)"] = played_s
    if kept_s - played_s > 0.05:
        timings[f"{name} (eval, earlier session)"] = kept_s - played_s


SHOWING_KEYS = ("run.progress", "run.rerun")  # how training is shown: may change on --resume, as with train --resume


def _what_is_trained(overrides, source: str) -> dict[str, tuple[object, str]]:
    """{key: (value, the override's text)} that the train overrides set, the later of two for one key
    winning as in the config; SHOWING_KEYS left out (they do not change what is trained)."""
    settings = {}
    for text in overrides:
        path, value = parse_override(text, source.format(text=text))
        key = ".".join(part.strip() for part in path)
        if key not in SHOWING_KEYS:
            settings[key] = (value, text.strip())
    return settings


def _arm_configs(overrides) -> dict[str, dict] | None:
    """{arm: its resolved train config as a dict} under the train overrides (SHOWING_KEYS left out), or
    None when one does not load (a layout file gone since, say): then only the overrides compare."""
    trained = [text for text in overrides if text.split("=", 1)[0].strip() not in SHOWING_KEYS]
    try:
        return {arm.name: to_dict(load_train_config([arm.config], ["name=check", "total_steps=1", "task.layout=0", *trained]))
                for arm in ARMS}
    except ValueError:
        return None


def _config_difference(then: dict[str, dict], now: dict[str, dict]) -> str:
    """The first setting in which two {arm: config} differ, as a phrase."""
    for name in then:
        diff = first_difference(then[name], now[name])
        if diff:
            return f"{diff[0]} is {diff[2]!r} now, {diff[1]!r} then (the {name} arm's config)"
    return "the arms' configs differ"


def _changed_settings(then, now, then_source: str) -> list[str]:
    """What the train overrides `now` set otherwise than `then` (read from `then_source`), one phrase
    per key ([] if nothing), each as the user typed it: '--train-set n_envs=3 (was n_envs=16)'."""
    before, after = _what_is_trained(then, then_source), _what_is_trained(now, "--train-set {text}")

    def same(a, b) -> bool:  # 16 and 16.0 alike, true and 1 not
        return a == b and isinstance(a, bool) == isinstance(b, bool)

    def flag(text: str) -> str:
        key, value = text.split("=", 1)
        return f"--train-fidelity {value}" if key.strip() == "task.fidelity" else f"--train-set {text}"

    changed = []
    for key in sorted(set(before) | set(after), key=lambda k: (k != "task.fidelity", k)):
        was, asked = before.get(key), after.get(key)
        if was is not None and asked is not None and same(was[0], asked[0]):
            continue
        if asked is None:
            changed.append(f"{flag(was[1])} is missing")
        elif was is None:
            changed.append(f"{flag(asked[1])} is new")
        else:
            changed.append(f"{flag(asked[1])} (was {flag(was[1]).split(' ', 1)[1]})")
    return changed


def _save_state(plan: StudyPlan, state: dict) -> None:
    atomic_write_text(plan.out / STATE_FILE, json.dumps(state, indent=2) + "\n")


def _finished_seconds(run_dir: Path) -> float | None:
    """Training seconds of a run whose last.pt shows it ended on its own (its max_minutes or
    total_steps used, its last row logged); None if it was interrupted before that."""
    data = load_checkpoint(run_dir / "last.pt")
    if not is_training_checkpoint(data) or data.get("pending_row"):
        return None
    cfg, c = train_config_from_dict(data["train_config"], str(run_dir / "last.pt")), data["counters"]
    seconds, steps = float(c.get("seconds", 0.0)), c.get("world_steps", 0)
    by_time = cfg.max_minutes > 0 and seconds >= 60.0 * cfg.max_minutes
    return seconds if by_time or steps >= cfg.total_steps else None


def _spent_minutes(run_dir: Path) -> float:
    """Minutes an interrupted run has trained so far (its checkpoint's counters)."""
    return float(load_checkpoint(run_dir / "last.pt")["counters"]["seconds"]) / 60.0


def _write(plan: StudyPlan, rows: Sequence, timings: dict[str, float], episodes: int, state: dict) -> None:
    """The table, its charts and timings.json; table.json's meta holds this session's budget and
    every session's (`state`'s record, this session's included) with their wall time."""
    paired, pairs = paired_report(rows, "heuristic", plan.eval_task.max_steps)
    atomic_write_text(plan.out / "table.txt", f"{table_heading(rows, plan.eval_task_name)}\n{format_table(rows)}\n" + (f"\n{paired}\n" if paired else ""))
    write_csv(rows, plan.out / "table.csv")
    sessions = {"session_budgets_minutes": state.get("budgets", [plan.budget_minutes]),
                "seconds_all_sessions": _earlier_sessions_seconds(state)}
    meta = {"budget_minutes": plan.budget_minutes, **sessions, "episodes": episodes,
            "layouts": [str(l) for l in plan.layouts], "seed": plan.seed, "paired": pairs_to_dicts(pairs),
            **_table_provenance(plan, state)}
    if plan.eval_task_name:  # as eval's JSON records it, for pool's heading
        meta["task_name"] = plan.eval_task_name
    write_json(rows, plan.out / "table.json", plan.eval_task, meta)
    plot_rows(rows, plan.out / "plots")
    atomic_write_text(plan.out / "timings.json", _timings_json(timings))


def _table_provenance(plan: StudyPlan, state: dict) -> dict:
    """What eval's tables record of what played them, for table.json, so that `pursuit-mj pool` checks
    a study's table as it checks eval's (a label that names two checkpoints, two arenas under one
    layout, code versions): each arm's label with its best.pt's sha256 (from the kept evaluation:
    the checkpoint its cells were played with), no policy files, the code, the layouts' files and
    identities and the evaders' model file."""
    kept = state.get("evaluation") or {}
    models = {}
    for key, sha in (kept.get("checkpoints") or {}).items():
        for cell in ((kept.get("cells") or {}).get(key) or {}).values():
            row = cell.get("row") if isinstance(cell, dict) else None
            if isinstance(row, dict) and isinstance(row.get("policy"), str):
                models[row["policy"]] = sha
    return {"model_sha256_of": models, "policy_file_sha256_of": {}, "code": provenance(),
            "layout_sha256": {layout_label(l): file_sha256(resolve_layout_ref(l)) for l in plan.layouts},
            "layout_identity": {layout_label(l): layout_identity(l) for l in plan.layouts},
            "evader_model_sha256": evader_model_sha256(plan.eval_task)}


def _timings_json(timings: dict[str, float]) -> str:
    return json.dumps({k: round(v, 1) for k, v in timings.items()}, indent=2) + "\n"


def format_timings(timings: dict[str, float], budget_minutes: float) -> str:
    """One line per part; the total (this session's) says how it compares with the budget (a busy
    machine, or arms that each need at least one update and a validation, can take the study over it).

    An arm's training time is its run's own clock (collection, updates, validations: the `seconds`
    of its metrics log), over every session that trained it; evaluations and totals are wall time."""
    width = max(len(k) for k in timings)
    lines = [f"  {k.ljust(width)}  {_duration(v):>8}" for k, v in timings.items()]
    over = timings["total"] / 60.0 - budget_minutes
    lines[list(timings).index("total")] += f" (budget {budget_minutes:g} min" + (f", {over:.1f} min over)" if over >= 0.05 else ")")
    return "\n".join(lines)
