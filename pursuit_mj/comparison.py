"""Paired comparison of two policies on the same episodes: is one really faster or surer?

Every policy of an evaluation table plays the same episodes (episode k of a layout has the
same seed for all; pursuit_mj.evaluation), so two policies can be compared episode by episode.
Differences of the same episode cancel what makes it long for everyone (where the evader
spawned, how the obstacles fell); their mean has a much narrower interval than the gap
between two independent means, and says with confidence when a policy is faster.

An episode's capture time here is its steps when it ended in success and max_steps when it
did not, so a policy gains nothing by crashing early.
"""

from __future__ import annotations

import dataclasses
from typing import Sequence

from .evaluation import Row, layout_identity
from .stats import Mean, mean_interval, sign_flip_p


MIN_VERDICT_EPISODES = 5  # paired episodes below which no faster/slower verdict is given
VERDICT_LEVEL = 0.05  # a verdict needs the sign-flip test's p below this, beside the 95 % interval


@dataclasses.dataclass(frozen=True)
class Paired:
    """`policy` against `reference` on one layout, over the same `episodes`.

    steps: mean of (policy - reference) capture time per episode, decision steps, with its
    95 % t interval (negative: the policy catches sooner). faster / slower: episodes where
    the policy's capture time is lower / higher. only_policy / only_reference: episodes that
    only that one of the two ended in success. p_value: two-sided p of the exact sign-flip
    test (stats.sign_flip_p); None above stats.SIGN_FLIP_MAX_TERMS nonzero differences.
    """

    policy: str
    reference: str
    layout: str
    episodes: int
    steps: Mean
    faster: int
    slower: int
    only_policy: int
    only_reference: int
    p_value: float | None = None

    @property
    def verdict(self) -> str:
        """'faster' / 'slower' when the 95 % interval excludes 0 and the sign-flip test agrees
        (p below VERDICT_LEVEL), else 'level'; 'too few' below MIN_VERDICT_EPISODES pairs (a t
        interval of two or three identical differences has width 0). The t interval alone is
        anti-conservative on a few differences that are mostly 0 (ties where both policies
        played alike), where the exact test is not."""
        if self.steps.n < MIN_VERDICT_EPISODES:
            return "too few"
        if self.p_value is not None and self.p_value >= VERDICT_LEVEL:
            return "level"
        if self.steps.hi is not None and self.steps.hi < 0:
            return "faster"
        if self.steps.lo is not None and self.steps.lo > 0:
            return "slower"
        return "level"


def pair(row: Row, reference: Row, max_steps: float) -> Paired:
    """Compare two rows of one table (same layout, seed and episodes); ValueError if they differ."""
    # a layout named two ways (0 and the built-in's file, x.yaml and ./x.yaml) plays the same episodes
    if ((layout_identity(row.layout), row.seed, row.fidelity)
            != (layout_identity(reference.layout), reference.seed, reference.fidelity)):
        raise ValueError(f"paired comparison: {row.policy} (layout {row.layout}, seed {row.seed}, {row.fidelity}) and "
                         f"{reference.policy} (layout {reference.layout}, seed {reference.seed}, {reference.fidelity}) "
                         "did not play the same episodes")
    a, b = row.capture_steps, reference.capture_steps
    if len(a) != len(b) or len(a) != row.episodes or len(b) != reference.episodes:
        raise ValueError(f"paired comparison on layout {row.layout}: {row.policy} has {len(a)} episode times and "
                         f"{reference.policy} {len(b)}; both need one per episode of the same table")
    diffs = [x - y for x, y in zip(a, b)]
    # a success beats a failure; two failures (both at max_steps) tie. From the outcomes where
    # the rows carry them: a capture on the very last step costs max_steps too
    won_a, won_b = _successes(row, max_steps), _successes(reference, max_steps)
    only_row = sum(x and not y for x, y in zip(won_a, won_b))
    only_ref = sum(y and not x for x, y in zip(won_a, won_b))
    return Paired(row.policy, reference.policy, row.layout, len(diffs),
                  mean_interval(diffs, (-float(max_steps), float(max_steps))),
                  sum(d < 0 for d in diffs), sum(d > 0 for d in diffs), only_row, only_ref, sign_flip_p(diffs))


def _successes(row: Row, max_steps: float) -> list[bool]:
    """Per episode of `row`: whether it ended in success (from its episode log, else from its
    capture steps, where a success on the last step cannot be told from a failure)."""
    if len(row.episode_log) == len(row.capture_steps):
        return [outcome == "success" for _, outcome, _, _ in row.episode_log]
    return [x < max_steps for x in row.capture_steps]


def pair_table(rows: Sequence[Row], reference: str, max_steps: float) -> list[Paired]:
    """Every other policy of `rows` against `reference`, layout by layout (ValueError if
    `reference` is not among them)."""
    refs = {layout_identity(r.layout): r for r in rows if r.policy == reference}
    if not refs:
        names = ", ".join(dict.fromkeys(r.policy for r in rows))
        raise ValueError(f"--versus {reference!r}: no such policy in the table (policies: {names})")
    keyed = [(r, layout_identity(r.layout)) for r in rows if r.policy != reference]
    return [pair(r, refs[key], max_steps) for r, key in keyed if key in refs]


def format_pairs(pairs: Sequence[Paired]) -> str:
    """A plain-text table of paired comparisons, one line each."""
    head = ["policy", "versus", "layout", "episodes", "capture steps, policy - versus [95% CI]", "faster / slower",
            "caught only by policy / versus", "p (sign-flip)", "verdict"]
    body = [[p.policy, p.reference, p.layout, str(p.episodes),
             f"{p.steps.mean:+7.1f} " + ("[no interval]" if p.steps.lo is None else f"[{p.steps.lo:+7.1f}, {p.steps.hi:+7.1f}]"),
             f"{p.faster} / {p.slower}",
             f"{p.only_policy} / {p.only_reference}", _p_text(p.p_value), p.verdict] for p in pairs]
    widths = [max(len(x) for x in col) for col in zip(head, *body)]
    return "\n".join("  ".join(c.ljust(w) for c, w in zip(line, widths)).rstrip() for line in [head] + body)


def _p_text(p: float | None) -> str:
    if p is None:
        return "-"
    return "<0.001" if p < 0.001 else f"{p:.3g}"


def pairs_to_dicts(pairs: Sequence[Paired]) -> list[dict]:
    """JSON-ready records of paired comparisons (steps in decision steps)."""
    return [{"policy": p.policy, "versus": p.reference, "layout": p.layout, "episodes": p.episodes,
             "capture_steps_diff": p.steps.mean, "capture_steps_diff_ci_lo": p.steps.lo,
             "capture_steps_diff_ci_hi": p.steps.hi, "faster": p.faster, "slower": p.slower,
             "caught_only_by_policy": p.only_policy, "caught_only_by_versus": p.only_reference,
             "sign_flip_p": p.p_value, "verdict": p.verdict} for p in pairs]


def paired_report(rows: Sequence[Row], reference: str, max_steps: float) -> tuple[str, list[Paired]]:
    """(text, pairs): every other policy of `rows` paired with `reference`, under a heading that
    says how to read it; ("", []) when `reference` is alone or absent."""
    if reference not in {r.policy for r in rows} or len({r.policy for r in rows}) < 2:
        return "", []
    pairs = pair_table(rows, reference, max_steps)
    head = (f"paired with {reference} on the same episodes (capture steps: steps of a success, {max_steps:g} "
            "for a failure; negative = sooner):")
    return head + "\n" + format_pairs(pairs), pairs
