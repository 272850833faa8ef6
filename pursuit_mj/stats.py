"""Confidence intervals for evaluation tables: Wilson score intervals for rates, t intervals for means,
the exact sign-flip test of paired differences, and the exact McNemar test of paired outcomes.

No SciPy: the 97.5 % Student t quantile comes from a table (4 decimals) up to 9 degrees
of freedom and from a Cornish-Fisher expansion (error below 1e-4) beyond.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Sequence

import numpy as np

Z95 = 1.959963984540054  # two-sided 95 % normal quantile


@dataclasses.dataclass(frozen=True)
class Rate:
    """`count` of `n` episodes; `p` = count / n; [lo, hi] the 95 % Wilson score interval (fractions)."""

    count: int
    n: int
    p: float
    lo: float
    hi: float


@dataclasses.dataclass(frozen=True)
class Mean:
    """Mean of `n` values with its 95 % t interval [lo, hi]; all None when n == 0."""

    n: int
    mean: float | None
    lo: float | None
    hi: float | None


def wilson_interval(count: int, n: int, z: float = Z95) -> tuple[float, float]:
    """Wilson score interval (lo, hi) of a binomial proportion count/n; (0, 1) when n == 0."""
    if n < 0 or count < 0 or count > n:
        raise ValueError(f"wilson_interval: need 0 <= count <= n, got count={count}, n={n}")
    if n == 0:
        return 0.0, 1.0
    p = count / n
    z2 = z * z
    denom = 1.0 + z2 / n
    centre = (p + z2 / (2 * n)) / denom
    half = z / denom * math.sqrt(p * (1 - p) / n + z2 / (4 * n * n))
    # exactly 0 and 1 at the ends (the formula leaves rounding dust such as 2.8e-17 there)
    lo = 0.0 if count == 0 else max(0.0, centre - half)
    hi = 1.0 if count == n else min(1.0, centre + half)
    return lo, hi


def rate(count: int, n: int) -> Rate:
    lo, hi = wilson_interval(count, n)
    return Rate(int(count), int(n), count / n if n else 0.0, lo, hi)


_T975_SMALL = (12.7062, 4.3027, 3.1824, 2.7764, 2.5706, 2.4469, 2.3646, 2.3060, 2.2622)


def t_quantile_975(dof: int) -> float:
    """The 0.975 quantile of Student's t with `dof` degrees of freedom (dof >= 1)."""
    if dof < 1:
        raise ValueError(f"t_quantile_975: degrees of freedom must be >= 1, got {dof}")
    if dof <= len(_T975_SMALL):
        return _T975_SMALL[dof - 1]
    z, v = Z95, float(dof)
    return (z + (z**3 + z) / (4 * v) + (5 * z**5 + 16 * z**3 + 3 * z) / (96 * v**2)
            + (3 * z**7 + 19 * z**5 + 17 * z**3 - 15 * z) / (384 * v**3)
            + (79 * z**9 + 776 * z**7 + 1482 * z**5 - 1920 * z**3 - 945 * z) / (92160 * v**4))


def mean_interval(values: Sequence[float], bounds: tuple[float, float] | None = None) -> Mean:
    """Mean and 95 % t interval; a single value has no interval (lo and hi None).

    bounds (lo, hi): the range the values can take (episode steps: 0..max_steps); the
    interval is cut to it, since a few skewed samples can stretch a t interval past it.
    """
    n = len(values)
    if n == 0:
        return Mean(0, None, None, None)
    m = math.fsum(values) / n
    if n == 1:
        return Mean(1, m, None, None)  # one sample says nothing of the spread
    var = math.fsum((x - m) ** 2 for x in values) / (n - 1)
    half = t_quantile_975(n - 1) * math.sqrt(var / n)
    lo, hi = m - half, m + half
    if bounds is not None:
        lo, hi = max(lo, bounds[0]), min(hi, bounds[1])
    return Mean(n, m, lo, hi)


SIGN_FLIP_MAX_TERMS = 100  # nonzero differences up to which sign_flip_p is computed exactly (above: None)


def sign_flip_p(diffs: Sequence[float]) -> float | None:
    """Two-sided p-value of the paired permutation (sign-flip) test that the mean difference is 0.

    Under the null, each episode's difference is as likely to have had the other sign, so
    the 2^n sums of +-|d_i| are equally likely; p is the share of them at least as far
    from 0 as the observed sum. Exact for any sample, unlike a t interval, which on a few
    differences that are mostly 0 claims more than the data hold. Differences must be
    integers (capture steps are step counts); the sums are counted by dynamic programming
    over the subset sums of |d_i|, O(n * sum |d_i|). Returns None above
    SIGN_FLIP_MAX_TERMS nonzero differences, where the t interval is reliable and the
    count would be slow; 1.0 when every difference is 0.
    """
    sizes = []
    for d in diffs:
        if d != round(d):
            raise ValueError(f"sign_flip_p: differences must be whole numbers (step counts), got {d}")
        if d != 0:
            sizes.append(abs(int(round(d))))
    if not sizes:
        return 1.0
    if len(sizes) > SIGN_FLIP_MAX_TERMS:
        return None
    total = sum(sizes)
    observed = abs(int(round(math.fsum(diffs))))
    # prob[s]: chance that the differences given a + sign sum to s; the signed sum is then 2 s - total
    prob = np.zeros(total + 1)
    prob[0] = 1.0
    reach = 0
    for a in sizes:
        prob[a : reach + a + 1] += prob[: reach + 1].copy()
        prob[: reach + a + 1] *= 0.5
        reach += a
    signed = 2 * np.arange(total + 1) - total
    return float(min(1.0, prob[np.abs(signed) >= observed].sum()))


def mcnemar_p(only_a: int, only_b: int) -> float:
    """Two-sided p-value of the exact McNemar test that two policies playing the same episodes
    succeed equally often.

    Only the discordant episodes count (`only_a`: won by policy a alone, `only_b`: by b alone);
    under the null each of them is a fair coin, so p = min(1, 2 P(X <= min(only_a, only_b)))
    with X ~ Binomial(only_a + only_b, 1/2). Exact (integer arithmetic) for any counts; 1.0
    when no episode was won by one side alone.
    """
    for name, v in (("only_a", only_a), ("only_b", only_b)):
        if isinstance(v, bool) or int(v) != v or v < 0:
            raise ValueError(f"mcnemar_p: {name} must be a count >= 0, got {v!r}")
    n, k = int(only_a) + int(only_b), int(min(only_a, only_b))
    if n == 0:
        return 1.0
    tail = sum(math.comb(n, i) for i in range(k + 1))
    return min(1.0, 2 * tail / 2**n)  # int / int: correctly rounded at any size


def percent_text(fraction: float) -> str:
    """A fraction as percent with one decimal, or as many more as keep a value that is neither
    0 nor 1 from printing as 0.0 or 100.0 (one collision in 2500 episodes is 0.04, not 0.0).
    The evaluation table's rates and the bar labels of its charts (plots.bar_label) both say it."""
    value = 100.0 * fraction
    decimals = 1
    while 0.0 < fraction < 1.0 and round(value, decimals) in (0.0, 100.0) and decimals < 12:
        decimals += 1
    return f"{value:.{decimals}f}"
