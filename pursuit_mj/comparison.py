"""Paired comparison of two policies on the same episodes: is one really faster or surer?

Every policy of an evaluation table plays the same episodes (episode k of a layout has the
same seed for all; pursuit_mj.evaluation), so two policies can be compared episode by episode.
Differences of the same episode cancel what makes it long for everyone (where the evader
spawned, how the obstacles fell); their mean has a much narrower interval than the gap
between two independent means, and says with confidence when a policy is faster.

An episode's capture time here is its steps when it ended in success and max_steps when it
did not, so a policy gains nothing by crashing early. Success is judged apart, on the episodes
only one of the two won (the exact McNemar test): those both won or both lost say nothing
about which is surer. A policy compared on two or more layouts gets one more comparison over
all their episodes (layout ALL_LAYOUTS), where a difference too small to show on one layout
may show on the whole.
"""

from __future__ import annotations

import dataclasses
from typing import Sequence

from .evaluation import Row, layout_identity, one_fidelity  # one_fidelity: the paired heading's, and pool's
from .stats import Mean, mcnemar_p, mean_interval, sign_flip_p


MIN_VERDICT_EPISODES = 5  # paired episodes below which no faster/slower verdict is given
VERDICT_LEVEL = 0.05  # a verdict needs the test's p below this (for steps: beside the 95 % interval)
ALL_LAYOUTS = "all"  # the layout label of a comparison over every layout's episodes


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
    success_p: float = 1.0
    fidelity: str = ""  # of both rows (a pooled table may hold several)

    @property
    def success_verdict(self) -> str:
        """'surer' / 'less sure' when the policy won more / fewer of the episodes only one of the
        two won and the exact McNemar test's p is below VERDICT_LEVEL, else 'level' (six to none
        is the fewest that can be called)."""
        if self.success_p >= VERDICT_LEVEL:
            return "level"
        return "surer" if self.only_policy > self.only_reference else "less sure"

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
    a, b, won_a, won_b = _aligned(row, reference, max_steps)
    return _compare(row.policy, reference.policy, row.layout, a, b, won_a, won_b, max_steps, row.fidelity)


def _aligned(row: Row, reference: Row, max_steps: float) -> tuple[list[float], list[float], list[bool], list[bool]]:
    """(capture steps of row, of reference, successes of row, of reference), episode by episode:
    in row's order, the reference's episode of the same seed beside each (the k-th of a seed met
    several times beside its k-th), from the rows' episode logs; by place where a row has no log
    (one made by hand from capture times alone). ValueError naming both rows unless they hold
    the same episodes, one capture time each."""
    a, b = list(row.capture_steps), list(reference.capture_steps)
    if len(a) != len(b) or len(a) != row.episodes or len(b) != reference.episodes:
        raise ValueError(f"paired comparison on layout {row.layout}: {row.policy} has {len(a)} episode times and "
                         f"{reference.policy} {len(b)}; both need one per episode of the same table")
    won_a, won_b = _successes(row, max_steps), _successes(reference, max_steps)
    if len(row.episode_log) != len(a) or len(reference.episode_log) != len(b):
        return a, b, won_a, won_b
    keys_a, keys_b = _episode_keys(row), _episode_keys(reference)
    if set(keys_a) != set(keys_b):
        only_a = sorted({s for s, _ in keys_a} - {s for s, _ in keys_b}) or sorted(set(keys_a) - set(keys_b))[:1]
        only_b = sorted({s for s, _ in keys_b} - {s for s, _ in keys_a}) or sorted(set(keys_b) - set(keys_a))[:1]
        raise ValueError(f"paired comparison on layout {row.layout}: {row.policy} and {reference.policy} did not play the "
                         f"same episodes ({_seeds_text(only_a)} of {row.policy} not among {reference.policy}'s; "
                         f"{_seeds_text(only_b)} of {reference.policy} not among {row.policy}'s)")
    place = {key: i for i, key in enumerate(keys_b)}
    order = [place[key] for key in keys_a]
    return a, [b[i] for i in order], won_a, [won_b[i] for i in order]


def _episode_keys(row: Row) -> list[tuple[int, int]]:
    """Per episode of `row`'s log: (its seed, how many episodes of that seed came before it)."""
    met: dict[int, int] = {}
    keys = []
    for seed, *_ in row.episode_log:
        keys.append((seed, met.get(seed, 0)))
        met[seed] = met.get(seed, 0) + 1
    return keys


def _seeds_text(items: list) -> str:
    """Some episode seeds (or (seed, repeat) keys) for an error line: 'episode seeds 3, 7 (2 more)'."""
    seeds = [str(x if isinstance(x, int) else f"{x[0]} (its #{x[1] + 1})") for x in items]
    more = f" ({len(seeds) - 3} more)" if len(seeds) > 3 else ""
    return f"episode seed{'s' if len(seeds) > 1 else ''} {', '.join(seeds[:3])}{more}"


def _compare(policy: str, reference: str, layout: str, a: Sequence[float], b: Sequence[float],
             won_a: Sequence[bool], won_b: Sequence[bool], max_steps: float, fidelity: str) -> Paired:
    """The Paired of capture times a, b and outcomes won_a, won_b (one per episode, same order)."""
    diffs = [x - y for x, y in zip(a, b, strict=True)]
    # a success beats a failure; two failures (both at max_steps) tie. From the outcomes where
    # the rows carry them: a capture on the very last step costs max_steps too
    only_row = sum(x and not y for x, y in zip(won_a, won_b, strict=True))
    only_ref = sum(y and not x for x, y in zip(won_a, won_b, strict=True))
    return Paired(policy, reference, layout, len(diffs),
                  mean_interval(diffs, (-float(max_steps), float(max_steps))),
                  sum(d < 0 for d in diffs), sum(d > 0 for d in diffs), only_row, only_ref, sign_flip_p(diffs),
                  mcnemar_p(only_row, only_ref), fidelity)


def pair_matches(matches: Sequence[tuple[Row, Row]], max_steps: float) -> list[Paired]:
    """`pair` on each (row, reference) of `matches` (each already on the same episodes), then,
    for every policy matched on two or more layouts (of one fidelity), one more Paired over all
    those episodes (layout ALL_LAYOUTS), after the per-layout ones."""
    out = [pair(r, ref, max_steps) for r, ref in matches]
    by_policy: dict[tuple[str, str, str], list[tuple[Row, Row]]] = {}
    for r, ref in matches:
        by_policy.setdefault((r.policy, ref.policy, r.fidelity), []).append((r, ref))
    for (policy, reference, fidelity), group in by_policy.items():
        if len(group) < 2:
            continue
        a, b, won_a, won_b = [], [], [], []
        for r, ref in group:
            for whole, part in zip((a, b, won_a, won_b), _aligned(r, ref, max_steps)):
                whole.extend(part)
        out.append(_compare(policy, reference, ALL_LAYOUTS, a, b, won_a, won_b, max_steps, fidelity))
    return out


def _successes(row: Row, max_steps: float) -> list[bool]:
    """Per episode of `row`: whether it ended in success (from its episode log, else from its
    capture steps, where a success on the last step cannot be told from a failure)."""
    if len(row.episode_log) == len(row.capture_steps):
        return [outcome == "success" for _, outcome, _, _ in row.episode_log]
    return [x < max_steps for x in row.capture_steps]


def pair_table(rows: Sequence[Row], reference: str, max_steps: float) -> list[Paired]:
    """Every other policy of `rows` against `reference`, layout by layout, and over all layouts
    where there are two or more (pair_matches; ValueError if `reference` is not among them)."""
    refs = {layout_identity(r.layout): r for r in rows if r.policy == reference}
    if not refs:
        names = ", ".join(dict.fromkeys(r.policy for r in rows))
        raise ValueError(f"--versus {reference!r}: no such policy in the table (policies: {names})")
    keyed = [(r, layout_identity(r.layout)) for r in rows if r.policy != reference]
    return pair_matches([(r, refs[key]) for r, key in keyed if key in refs], max_steps)


def format_pairs(pairs: Sequence[Paired]) -> str:
    """A plain-text table of paired comparisons, one line each (a fidelity column when they are
    of several fidelities, as a pooled table's may be)."""
    several = len({p.fidelity for p in pairs}) > 1
    head = ["policy", "versus", "layout", *(["fidelity"] if several else []), "episodes",
            "capture steps, policy - versus [95% CI]", "faster / slower",
            "p (sign-flip)", "steps verdict", "caught only by policy / versus", "p (McNemar)", "success verdict"]
    body = [[p.policy, p.reference, p.layout, *([p.fidelity] if several else []), str(p.episodes),
             f"{p.steps.mean:+7.1f} " + ("[no interval]" if p.steps.lo is None else f"[{p.steps.lo:+7.1f}, {p.steps.hi:+7.1f}]"),
             f"{p.faster} / {p.slower}", p_value_text(p.p_value), p.verdict,
             f"{p.only_policy} / {p.only_reference}", p_value_text(p.success_p), p.success_verdict] for p in pairs]
    widths = [max(len(x) for x in col) for col in zip(head, *body)]
    return "\n".join("  ".join(c.ljust(w) for c, w in zip(line, widths)).rstrip() for line in [head] + body)


def p_value_text(p: float | None) -> str:
    """A p-value to 3 significant digits ('-' for none, '<0.001' below it), or to as many more as
    keep one below VERDICT_LEVEL from printing as it (0.049983 as 0.04998, not 0.05 beside a verdict)."""
    if p is None:
        return "-"
    if p < 0.001:
        return "<0.001"
    digits = 3
    while p < VERDICT_LEVEL <= float(f"{p:.{digits}g}") and digits < 12:
        digits += 1
    return f"{p:.{digits}g}"


def pairs_to_dicts(pairs: Sequence[Paired]) -> list[dict]:
    """JSON-ready records of paired comparisons (steps in decision steps)."""
    return [{"policy": p.policy, "versus": p.reference, "layout": p.layout, "fidelity": p.fidelity, "episodes": p.episodes,
             "capture_steps_diff": p.steps.mean, "capture_steps_diff_ci_lo": p.steps.lo,
             "capture_steps_diff_ci_hi": p.steps.hi, "faster": p.faster, "slower": p.slower,
             "caught_only_by_policy": p.only_policy, "caught_only_by_versus": p.only_reference,
             "sign_flip_p": p.p_value, "verdict": p.verdict,
             "mcnemar_p": p.success_p, "success_verdict": p.success_verdict} for p in pairs]


def paired_report(rows: Sequence[Row], reference: str, max_steps: float) -> tuple[str, list[Paired]]:
    """(text, pairs): every other policy of `rows` paired with `reference`, under a heading that
    says how to read it (and names the fidelity when the pairs are of one: one_fidelity); ("", [])
    when `reference` is alone or absent."""
    if reference not in {r.policy for r in rows} or len({r.policy for r in rows}) < 2:
        return "", []
    pairs = pair_table(rows, reference, max_steps)
    return paired_heading(reference, "the same episodes", pairs, max_steps) + "\n" + format_pairs(pairs), pairs


def paired_heading(reference: str, episodes: str, pairs: Sequence[Paired], max_steps: float) -> str:
    """The line over a paired table (eval's, pool's): whom the policies are paired with, on which
    `episodes`, in which fidelity when the pairs are of one, and how to read both of its tests."""
    return (f"paired with {reference} on {episodes}{one_fidelity(pairs, ',')} (capture steps: steps of a success, {max_steps:g} "
            "for a failure; negative = sooner; success: judged on the episodes only one of the two won):")
