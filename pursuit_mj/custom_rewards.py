"""Reward terms of one's own, paid beside the task's named terms (docs/env_api.md, "Reward terms of your own").

A term is a callable `term(step: StepView) -> (W, N)` real array: each pursuer's reward for the
decision step just taken, already scaled. `PursuitEnv(extra_rewards={name: term})` adds it to
the reward, to info["reward_terms"], to the episode returns and to snapshots under its name;
`pursuit-mj train --reward FILE.py:NAME` adds the function NAME of FILE in training. A term
reads the step, it never changes it: every array of the StepView is read-only.
"""

from __future__ import annotations

import dataclasses
import keyword
from pathlib import Path
from typing import Callable, Mapping

import numpy as np

from .config import TaskConfig
from .rewards import REWARD_TERMS
from .user_file import UserCodeError, checked_real_array, load_named, what_and_where


@dataclasses.dataclass(frozen=True)
class StepView:
    """One decision step of every world, as a reward term sees it (read-only arrays).

    Shapes: W worlds, N pursuers, M evaders. Positions (m) and velocities (m/s) in the layout
    frame (origin at the arena's lower-left corner, x right, y up), at the end of the step
    unless named `_before`.
    - actions (W, N, 2): the actions given, fractions of pursuer_speed, each component clipped to
      [-1, 1] (the physics then caps the command's norm at pursuer_speed: (1, 1) flies at 1);
    - pursuer_pos_before, pursuer_pos, pursuer_vel (W, N, 2); evader_pos_before, evader_pos,
      evader_vel (W, M, 2);
    - free_before (W, M) bool: the evader was free when the step began; new_captures (W, M)
      bool: caught in this step; captured (W, M) bool: caught by its end;
    - collided (W, N) bool: the pursuer broke a clearance or touched something in the step;
      obstacle_gap (W, N) m: its centre's distance to the nearest surface of the layout's
      obstacles (this episode's random ones included) and border: what the task's clearance
      rule (obstacle_clearance, in `collided`) and proximity term measure. Caught evaders are
      not in it: one stays where it was caught as a body that a pursuer collides with only by
      touching it (a contact, in `collided`), with no clearance or proximity zone around it, as
      its catcher is within capture_radius of it; a pursuer's distance to one is to evader_pos
      where captured. Teammates are in nearest_mate;
      nearest_mate (W, N) m: to the nearest teammate (inf without teammates);
    - known_before, known (W, N, M) bool: the pursuer knew the evader (saw it, had it relayed
      by a teammate, or it is caught) when the step began / at its end; seen (W, N, M) bool:
      saw it directly at the end of the step;
    - steps (W,) int: decision steps of each world's episode, this one included;
    - outcome (W,) str: "success", "collision" or "timeout" where the step ended the
      episode, "" where it goes on.
    Worlds whose episode had already ended (no auto reset) are in the arrays too; their
    terms are set to 0 whatever the callable returns, as the task's own terms are. So are those
    of a world whose physics diverged in the step (a violent crash, ended as a "collision"):
    its positions after the step are MuJoCo's reset, not the drones', so a term is 0 there as
    the task's measured terms are, while the task's collision penalty is paid.
    """

    config: TaskConfig
    actions: np.ndarray
    pursuer_pos_before: np.ndarray
    pursuer_pos: np.ndarray
    pursuer_vel: np.ndarray
    evader_pos_before: np.ndarray
    evader_pos: np.ndarray
    evader_vel: np.ndarray
    free_before: np.ndarray
    new_captures: np.ndarray
    captured: np.ndarray
    collided: np.ndarray
    obstacle_gap: np.ndarray
    nearest_mate: np.ndarray
    known_before: np.ndarray
    known: np.ndarray
    seen: np.ndarray
    steps: np.ndarray
    outcome: np.ndarray

    def __post_init__(self):
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            if isinstance(value, np.ndarray):
                frozen = value.copy()  # a term that writes into its input gets an error, not a changed env
                frozen.flags.writeable = False
                object.__setattr__(self, field.name, frozen)


RewardTerm = Callable[[StepView], np.ndarray]


def checked_extra_rewards(extra: Mapping[str, RewardTerm] | None, source: str = "extra_rewards") -> dict[str, RewardTerm]:
    """`extra` as a dict, each name usable and not one of the task's terms, each term callable;
    ValueError naming `source` otherwise."""
    if extra is None:
        return {}
    if not isinstance(extra, Mapping):
        raise ValueError(f"{source}: expected a mapping of term name -> callable(StepView), got {type(extra).__name__}")
    out = {}
    for name, term in extra.items():
        if not isinstance(name, str) or not name.isidentifier() or keyword.iskeyword(name):
            raise ValueError(f"{source}: {name!r} is not a usable term name (letters, digits and _, not starting with a digit)")
        if name in REWARD_TERMS:
            raise ValueError(f"{source}: {name!r} is one of the task's own reward terms ({', '.join(REWARD_TERMS)}); "
                             f"give yours another name (a task term is scaled by its task key, e.g. task.{name}_reward)")
        if not callable(term):
            raise ValueError(f"{source}: the term {name!r} is {term!r}, not a callable taking a StepView")
        out[name] = term
    return out


@dataclasses.dataclass(frozen=True)
class FileTerm:
    """A term loaded from FILE.py:NAME; `source` ("--reward FILE.py:NAME") names it in errors."""

    function: RewardTerm
    source: str

    def __call__(self, step: StepView) -> np.ndarray:
        """The term's payment (W, N) (unitless reward, unchecked: see `term_values`)."""
        return self.function(step)


def term_values(name: str, term: RewardTerm, step: StepView, shape: tuple[int, int], where: str,
                paid: np.ndarray | None = None) -> np.ndarray:
    """What `term` pays for `step`, checked: (W, N) float32, finite; ValueError naming the term
    and `where` (the argument it came from; a FileTerm's own source instead) for anything else
    (a UserCodeError, which a rollout worker sends back as it is). `paid` (W,) bool: the worlds
    whose terms count (None: all); elsewhere what the term returned is not checked beyond its
    shape and comes back as 0, as the env pays nothing there (a NaN in a frozen world is no error)."""
    if isinstance(term, FileTerm):
        where, term = term.source, term.function
    try:
        raw = term(step)
    except (Exception, SystemExit) as exc:  # the user's own code: say which term failed, and where
        path = getattr(getattr(term, "__code__", None), "co_filename", None)
        said = what_and_where(exc, Path(path)) if path else f"{type(exc).__name__}: {exc}"
        raise UserCodeError(f"{where}: reward term {name!r} raised {said}") from exc
    values = checked_real_array(raw, shape, f"{where}: reward term {name!r}", "(worlds, pursuers)", "(world, pursuer)",
                                kinds="fiub", counted=paid)
    if paid is not None:
        values = np.where(paid[:, None], values, 0.0)
    too_large = np.abs(values) > np.finfo(np.float32).max  # inf once cast: say what it returned
    if too_large.any():
        bad = tuple(int(i) for i in np.argwhere(too_large)[0])
        raise UserCodeError(f"{where}: reward term {name!r} returned {values[bad]:g} at (world, pursuer) {bad}, "
                              f"beyond float32 (the reward's type)")
    return values.astype(np.float32)


def load_reward_file(ref: str, source: str = "--reward") -> tuple[str, RewardTerm]:
    """(NAME, the callable NAME of FILE) for a FILE.py:NAME reference: the term is paid under
    NAME. ValueError naming `source` and `ref` for a file or NAME that cannot be loaded."""
    function, _, name = load_named(ref, source, "function")
    checked_extra_rewards({name: function}, f"{source} {ref}")
    return name, FileTerm(function, f"{source} {ref}")


def load_reward_files(refs, source: str = "--reward") -> dict[str, RewardTerm]:
    """The terms of several FILE.py:NAME references by NAME; ValueError for two of one NAME."""
    out: dict[str, RewardTerm] = {}
    for ref in refs:
        name, term = load_reward_file(ref, source)
        if name in out:
            raise ValueError(f"{source} {ref}: a term {name!r} is already given ({', '.join(refs)}); a term is "
                             f"logged by its NAME, so two of one NAME cannot be told apart")
        out[name] = term
    return out
