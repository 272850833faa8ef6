"""Paired comparison on the same episodes (pursuit_mj.comparison)."""

import dataclasses

import pytest

from pursuit_mj.comparison import format_pairs, pair, pair_matches, pair_table
from pursuit_mj.config import default_config
from pursuit_mj.env import EpisodeRecord
from pursuit_mj.evaluation import evaluate, summarise
from pursuit_mj.heuristic import HeuristicTeam
from pursuit_mj.policy import RandomPolicy
from pursuit_mj.stats import t_quantile_975

MAX = 1000


def cells(table: str) -> dict[str, str]:
    """The first body line of a format_pairs table, by column heading (columns start where their heading does)."""
    head, line = table.splitlines()[:2]
    names = [h for h in head.split("  ") if h.strip()]
    starts = [head.index(h) for h in names] + [None]
    return {h.strip(): line[a:b].strip() for h, a, b in zip(names, starts, starts[1:])}


def row(policy, episodes, seed=5, layout="0"):
    records = [EpisodeRecord(0, k, 0, outcome, steps, None, {}, 0, layout) for k, (outcome, steps) in enumerate(episodes)]
    return summarise(policy, layout, "point", seed, records, MAX)


def test_differences_are_taken_episode_by_episode_and_failures_count_as_max_steps():
    ref = row("heuristic", [("success", 200), ("success", 300), ("success", 400), ("timeout", MAX)])
    pol = row("net", [("success", 190), ("success", 280), ("collision", 50), ("success", 600)])
    p = pair(pol, ref, MAX)
    diffs = [-10, -20, MAX - 400, 600 - MAX]  # the early collision costs the policy, not gains it
    mean = sum(diffs) / 4
    sd = (sum((d - mean) ** 2 for d in diffs) / 3) ** 0.5
    assert p.steps.mean == pytest.approx(mean)
    assert p.steps.hi - p.steps.mean == pytest.approx(min(t_quantile_975(3) * sd / 2, MAX - mean))
    assert (p.faster, p.slower, p.only_policy, p.only_reference) == (3, 1, 1, 1)
    assert p.verdict == "too few"  # 4 pairs


def test_a_capture_on_the_last_step_counts_as_caught_only_by_that_policy():
    ref = row("heuristic", [("timeout", MAX), ("success", 300)])
    pol = row("net", [("success", MAX), ("timeout", MAX)])  # caught on the very last step; lost the other
    p = pair(pol, ref, MAX)
    assert (p.only_policy, p.only_reference) == (1, 1)
    assert p.steps.mean == pytest.approx((0 + MAX - 300) / 2)  # the last-step capture costs max_steps, as a failure


def test_a_steady_gain_is_called_faster_even_when_the_means_overlap():
    """Episode lengths spread widely (their means' intervals overlap), but the policy is 10 steps
    sooner in every episode: pairing sees it."""
    lengths = [150, 420, 260, 610, 330, 180, 505, 240]
    ref = row("heuristic", [("success", s) for s in lengths])
    pol = row("net", [("success", s - 10) for s in lengths])
    assert pol.steps.hi > ref.steps.lo  # unpaired, no difference can be claimed
    p = pair(pol, ref, MAX)
    assert p.steps.mean == pytest.approx(-10) and p.steps.lo == p.steps.hi == pytest.approx(-10)
    assert p.verdict == "faster" and (p.faster, p.slower) == (8, 0)
    assert pair(ref, pol, MAX).verdict == "slower"
    assert "faster" in format_pairs([p]) and "-10.0" in format_pairs([p])


def test_rows_of_other_episodes_are_refused():
    a = row("a", [("success", 100)] * 3, seed=1)
    b = row("b", [("success", 100)] * 3, seed=2)
    with pytest.raises(ValueError, match="did not play the same episodes"):
        pair(a, b, MAX)
    with pytest.raises(ValueError, match="--versus 'c': no such policy in the table \\(policies: a, b\\)"):
        pair_table([a, b], "c", MAX)


def test_a_policy_against_itself_on_a_real_table_is_level_to_the_step():
    config = default_config(fidelity="point", max_steps=60)
    rows = []
    for label, policy in (("heuristic", HeuristicTeam.from_config(config)), ("again", HeuristicTeam.from_config(config)),
                          ("random", RandomPolicy(0))):
        rows += evaluate(policy, config, [0], episodes=4, seed=3, n_worlds=2, label=label)
    same, rnd = pair_table(rows, "heuristic", config.max_steps)
    assert same.steps.mean == 0 and same.steps.lo == same.steps.hi == 0
    assert same.verdict == "too few"  # 4 pairs: no verdict, however clear
    assert (same.faster, same.slower) == (0, 0)
    assert rnd.policy == "random" and rnd.episodes == 4


def test_no_verdict_and_no_interval_from_too_few_episodes():
    one = pair(row("net", [("success", 400)]), row("heuristic", [("success", 300)]), MAX)
    assert one.steps.mean == 100 and one.steps.lo is None and one.verdict == "too few"
    assert "[no interval]" in format_pairs([one])
    two = pair(row("net", [("success", 400), ("success", 500)]), row("heuristic", [("success", 300), ("success", 400)]), MAX)
    assert two.steps.lo == two.steps.hi == 100 and two.verdict == "too few"  # a t interval of width 0 proves nothing


def test_a_few_large_differences_among_ties_are_not_called_slower():
    """Twelve episodes, eight identical and four slower: a t interval excludes 0, but of the
    16 equally likely sign patterns of the four, two are as extreme (p = 0.125)."""
    lengths = [150, 420, 260, 610, 330, 180, 505, 240, 300, 350, 280, 220]
    extra = [0] * 8 + [30, 40, 25, 50]
    ref = row("heuristic", [("success", s) for s in lengths])
    pol = row("net", [("success", s + e) for s, e in zip(lengths, extra)])
    p = pair(pol, ref, MAX)
    assert p.steps.lo > 0  # the t interval alone would say slower
    assert p.p_value == pytest.approx(0.125)
    assert p.verdict == "level"
    got = cells(format_pairs([p]))
    assert got["p (sign-flip)"] == "0.125" and got["steps verdict"] == "level"


def test_sign_flip_p_counts_every_sign_pattern():
    from itertools import product

    from pursuit_mj.stats import sign_flip_p

    for diffs in ([3, -1, 4, 0, -5, 9, 2], [7, 7, 7, 7, 7], [0, 0], [-12, 30, 5, 5, -1, 8, 0, 13]):
        observed = abs(sum(diffs))
        patterns = list(product((1, -1), repeat=len(diffs)))
        exact = sum(abs(sum(s * d for s, d in zip(signs, diffs))) >= observed for signs in patterns) / len(patterns)
        assert sign_flip_p(diffs) == pytest.approx(exact, abs=1e-12)
    assert sign_flip_p([-10] * 5) == pytest.approx(2 / 32)  # five of five sooner: not yet below 0.05
    with pytest.raises(ValueError, match="whole numbers.*2.5"):
        sign_flip_p([1, 2.5])


def test_mcnemar_p_is_the_exact_binomial_test_on_the_episodes_only_one_policy_won():
    from math import comb

    from pursuit_mj.stats import mcnemar_p

    for b, c in ((6, 0), (10, 2), (3, 4), (40, 25), (1, 0)):
        n, k = b + c, min(b, c)
        tail = sum(comb(n, i) for i in range(k + 1)) / 2**n
        assert mcnemar_p(b, c) == pytest.approx(min(1.0, 2 * tail), abs=1e-12)
        assert mcnemar_p(c, b) == mcnemar_p(b, c)
    assert mcnemar_p(0, 0) == 1.0
    assert mcnemar_p(6, 0) == pytest.approx(1 / 32)  # six of six: the fewest that can be called
    assert mcnemar_p(5, 0) == pytest.approx(1 / 16)
    assert mcnemar_p(2000, 1900) == pytest.approx(0.1136, abs=2e-3)  # large counts stay finite and exact
    with pytest.raises(ValueError, match="-1"):
        mcnemar_p(-1, 3)


def test_catching_more_is_called_surer_only_when_the_episodes_won_by_one_side_say_so():
    """Success is judged on the episodes only one of the two won (McNemar): those both won or
    both lost say nothing about which is surer."""
    def pair_of(only_pol, only_ref, both=10, neither=4):
        ref = row("heuristic", [("success", 300)] * (both + only_ref) + [("timeout", MAX)] * (only_pol + neither))
        pol = row("net", [("success", 300)] * both + [("timeout", MAX)] * only_ref + [("success", 300)] * only_pol
                  + [("timeout", MAX)] * neither)
        return pair(pol, ref, MAX)

    six = pair_of(6, 0)
    assert (six.only_policy, six.only_reference) == (6, 0)
    assert six.success_p == pytest.approx(1 / 32) and six.success_verdict == "surer"
    assert pair_of(0, 6).success_verdict == "less sure"
    assert pair_of(5, 0).success_verdict == "level"  # p = 1/16
    assert pair_of(7, 2).success_verdict == "level"  # p = 0.18
    none = pair_of(0, 0)
    assert none.success_p == 1.0 and none.success_verdict == "level"
    got = cells(format_pairs([six]))
    assert (got["caught only by policy / versus"], got["p (McNemar)"], got["success verdict"]) == ("6 / 0", "0.0312", "surer")


def test_two_layouts_or_more_get_one_more_line_over_all_their_episodes():
    ref0 = row("heuristic", [("success", 200), ("success", 300), ("timeout", MAX)], layout="0")
    pol0 = row("net", [("success", 180), ("success", 320), ("success", 700)], layout="0")
    ref1 = row("heuristic", [("success", 400), ("collision", 20)], layout="1")
    pol1 = row("net", [("timeout", MAX), ("success", 500)], layout="1")
    pairs = pair_table([ref0, pol0, ref1, pol1], "heuristic", MAX)
    assert [p.layout for p in pairs] == ["0", "1", "all"]
    total = pairs[-1]
    diffs = [-20, 20, 700 - MAX, MAX - 400, 500 - MAX]
    assert total.episodes == 5 and total.steps.mean == pytest.approx(sum(diffs) / 5)
    assert (total.only_policy, total.only_reference) == (2, 1)
    assert (total.faster, total.slower) == (3, 2)
    assert [p.layout for p in pair_table([ref0, pol0], "heuristic", MAX)] == ["0"]  # one layout: nothing to pool


def test_a_p_value_just_below_the_verdict_level_does_not_print_as_it():
    """150 episodes won by the policy alone to 117 by the team give p = 0.049983: printed '0.05' beside the
    verdict 'surer', which needs p below 0.05."""
    from pursuit_mj.comparison import VERDICT_LEVEL, p_value_text
    from pursuit_mj.stats import mcnemar_p

    p = mcnemar_p(150, 117)
    assert p < VERDICT_LEVEL
    assert float(p_value_text(p)) < VERDICT_LEVEL and p_value_text(p) == "0.04998"
    assert [p_value_text(x) for x in (0.05, 0.125, 0.0625, 0.00781, 0.0005, 1.0, None)] == \
        ["0.05", "0.125", "0.0625", "0.00781", "<0.001", "1", "-"]


def test_sign_flip_p_counts_only_nonzero_differences_toward_its_exact_limit():
    from pursuit_mj.stats import SIGN_FLIP_MAX_TERMS, sign_flip_p

    assert SIGN_FLIP_MAX_TERMS == 100
    # ties (difference 0) flip to themselves: 150 of them beside six equal gains leave p = 2 / 2^6
    assert sign_flip_p([0] * 150 + [2] * 6) == pytest.approx(2 / 64, abs=1e-15)
    # exactly the limit is still computed (only the two all-same-sign patterns reach |sum| = 100) ...
    assert sign_flip_p([1] * 100) == pytest.approx(2 / 2**100, rel=1e-9)
    assert sign_flip_p([0] * 50 + [1] * 100) == pytest.approx(2 / 2**100, rel=1e-9)
    # ... one more nonzero difference is not
    assert sign_flip_p([1] * 101) is None


def test_more_differences_than_the_exact_test_takes_are_judged_by_the_t_interval():
    """Above SIGN_FLIP_MAX_TERMS nonzero differences p_value is None: the verdict comes from the
    t interval alone (no TypeError comparing None with the verdict level)."""
    lengths = [200 + 7 * k for k in range(120)]
    ref = row("heuristic", [("success", s) for s in lengths])
    sooner = pair(row("net", [("success", s - 10 + k % 3) for k, s in enumerate(lengths)]), ref, MAX)
    assert sooner.p_value is None and sooner.verdict == "faster"
    assert sooner.steps.mean == pytest.approx(-9)  # 40 each of -10, -9, -8
    mixed = pair(row("net", [("success", s + (5 if k % 2 else -5)) for k, s in enumerate(lengths)]), ref, MAX)
    assert mixed.p_value is None and mixed.steps.lo < 0 < mixed.steps.hi and mixed.verdict == "level"


def test_five_paired_episodes_are_enough_for_a_verdict():
    """MIN_VERDICT_EPISODES = 5: four pairs say 'too few', five are judged (here level: the
    sign-flip p of five sooner episodes is 2/32, not below 0.05)."""
    five = pair(row("net", [("success", 190)] * 5), row("heuristic", [("success", 200)] * 5), MAX)
    assert five.p_value == pytest.approx(2 / 32) and five.verdict == "level"
    four = pair(row("net", [("success", 190)] * 4), row("heuristic", [("success", 200)] * 4), MAX)
    assert four.verdict == "too few"


def test_rows_of_another_fidelity_or_with_missing_episode_times_are_refused():
    import dataclasses

    records = [EpisodeRecord(0, k, 0, "success", 100, None, {}, 0, "0") for k in range(3)]
    point = summarise("a", "0", "point", 5, records, MAX)
    quad = summarise("b", "0", "quadrotor", 5, records, MAX)
    with pytest.raises(ValueError, match="did not play the same episodes"):
        pair(point, quad, MAX)
    # one row of 3 episodes against one of 2: not zipped down to 2 pairs
    with pytest.raises(ValueError, match="a has 3 episode times and b 2"):
        pair(point, summarise("b", "0", "point", 5, records[:2], MAX), MAX)
    # a reference row whose times fall short of its own episode count
    cut = dataclasses.replace(summarise("b", "0", "point", 5, records, MAX), episodes=4)
    with pytest.raises(ValueError, match="episode times"):
        pair(point, cut, MAX)


def test_the_line_over_all_layouts_counts_each_episode_won_by_one_side_alone():
    ref0 = row("heuristic", [("success", 300)] * 3 + [("timeout", MAX)], layout="0")
    pol0 = row("net", [("success", 300), ("timeout", MAX), ("timeout", MAX), ("timeout", MAX)], layout="0")
    ref1 = row("heuristic", [("timeout", MAX)] * 2, layout="1")
    pol1 = row("net", [("success", 300)] * 2, layout="1")
    first, second, total = pair_table([ref0, pol0, ref1, pol1], "heuristic", MAX)
    assert (first.only_policy, first.only_reference) == (0, 2)
    assert (second.only_policy, second.only_reference) == (2, 0)
    assert (total.layout, total.episodes, total.only_policy, total.only_reference) == ("all", 6, 2, 2)
    assert total.success_p == 1.0  # 2 to 2: 2 * P(X <= 2), X ~ Bin(4, 1/2), = 2 * 11/16, cut to 1


def test_rows_without_an_episode_log_count_a_time_of_max_steps_as_a_failure():
    import dataclasses

    ref = dataclasses.replace(row("heuristic", [("success", 300), ("timeout", MAX)]), episode_log=())
    pol = dataclasses.replace(row("net", [("timeout", MAX), ("success", 200)]), episode_log=())
    p = pair(pol, ref, MAX)
    assert (p.only_policy, p.only_reference) == (1, 1)


def test_a_policy_on_a_layout_the_reference_did_not_play_is_left_unpaired():
    ref0 = row("heuristic", [("success", 200)] * 2, layout="0")
    pol0 = row("net", [("success", 180)] * 2, layout="0")
    pol1 = row("net", [("success", 180)] * 2, layout="1")
    assert [p.layout for p in pair_table([ref0, pol0, pol1], "heuristic", MAX)] == ["0"]


def test_the_fidelity_column_appears_only_when_the_pairs_are_of_several_fidelities():
    p = pair(row("net", [("success", 180)] * 2), row("heuristic", [("success", 200)] * 2), MAX)
    head = format_pairs([p]).splitlines()[0]
    assert head.split()[:4] == ["policy", "versus", "layout", "episodes"] and "fidelity" not in head


def test_a_reference_alone_in_its_table_gives_no_paired_report():
    from pursuit_mj.comparison import paired_report

    alone = [row("heuristic", [("success", 200)] * 2, layout=layout) for layout in ("0", "1")]
    assert paired_report(alone, "heuristic", MAX) == ("", [])
    assert paired_report(alone, "net", MAX) == ("", [])


def seeded_row(policy, episodes, layout="0"):
    """A row of (episode seed, outcome, steps) records, in the order given."""
    records = [EpisodeRecord(0, k, s, outcome, steps, None, {}, 0, layout) for k, (s, outcome, steps) in enumerate(episodes)]
    return summarise(policy, layout, "point", 5, records, MAX)


def test_episodes_are_paired_by_their_seeds_not_by_their_places_in_the_rows():
    """pair() took episode k of one row against episode k of the other: two rows holding the same
    episodes in another order were paired episode 0 against episode 1 (here: a policy 10 steps
    sooner in each episode read as 'level', +-290 steps)."""
    ref = seeded_row("heuristic", [(11, "success", 100), (22, "success", 400), (33, "success", 250),
                                   (44, "success", 600), (55, "success", 330), (66, "success", 180)])
    pol = seeded_row("net", [(22, "success", 390), (11, "success", 90), (44, "success", 590),
                             (33, "success", 240), (66, "success", 170), (55, "success", 320)])
    p = pair(pol, ref, MAX)
    assert p.steps.mean == pytest.approx(-10) and (p.faster, p.slower) == (6, 0) and p.verdict == "faster"
    both = pair_matches([(pol, ref), (dataclasses.replace(pol, layout="1"), dataclasses.replace(ref, layout="1"))], MAX)
    assert both[-1].layout == "all" and both[-1].steps.mean == pytest.approx(-10) and both[-1].faster == 12


def test_rows_of_other_episodes_are_refused_naming_both():
    """Two rows of one layout, seed, fidelity and count that hold other episodes (a row edited or
    assembled by hand, records of another seed list) were paired silently, episode by place."""
    ref = seeded_row("heuristic", [(11, "success", 100), (22, "success", 400), (33, "timeout", MAX)])
    pol = seeded_row("net", [(11, "success", 90), (23, "success", 390), (34, "success", 500)])
    with pytest.raises(ValueError) as err:
        pair(pol, ref, MAX)
    text = str(err.value)
    assert "\n" not in text and "net" in text and "heuristic" in text and "same episodes" in text
    assert "23" in text and "22" in text  # an episode seed each holds that the other does not
