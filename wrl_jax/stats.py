"""Confidence intervals over seeds: the one statistics helper of the project.

Every reported mean over seeds (experiments, sweeps, planners' throughput over
episodes) goes through :func:`mean_ci`. Student's t critical values come from a
closed-form CDF (no SciPy needed).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np


def _t_two_sided_mass(t: float, df: int) -> float:
    """P(|T| < t) for Student's t with an integer ``df`` (closed form, Abramowitz & Stegun 26.7.3-4)."""
    theta = math.atan(t / math.sqrt(df))
    s, c2 = math.sin(theta), math.cos(theta) ** 2
    if df % 2 == 1:
        if df == 1:
            return 2.0 * theta / math.pi
        term, total = 1.0, 1.0
        for k in range(2, df - 1, 2):  # 1 + 2/3 c^2 + (2*4)/(3*5) c^4 + ... (up to c^(df-3))
            term *= c2 * k / (k + 1)
            total += term
        return 2.0 / math.pi * (theta + s * math.sqrt(c2) * total)
    term, total = 1.0, 1.0
    for k in range(1, df - 2, 2):  # 1 + 1/2 c^2 + (1*3)/(2*4) c^4 + ... (up to c^(df-2))
        term *= c2 * k / (k + 1)
        total += term
    return s * total


def t_quantile(level: float, df: int) -> float:
    """Two-sided critical value: ``t`` with ``P(|T| < t) = level`` for ``df`` degrees of freedom.

    Bisection on the closed-form CDF (no SciPy needed), accurate to ~1e-10.
    """
    if not 0.0 < level < 1.0:
        raise ValueError(f"confidence level must be in (0, 1), got {level}")
    if int(df) != df or df < 1:
        raise ValueError(f"degrees of freedom must be a positive integer, got {df}")
    lo, hi = 0.0, 1.0
    while _t_two_sided_mass(hi, int(df)) < level:
        hi *= 2.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if _t_two_sided_mass(mid, int(df)) < level:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


@dataclasses.dataclass(frozen=True)
class Interval:
    """A mean and its confidence interval over ``n`` values (NaN values are dropped)."""

    mean: float
    low: float
    high: float
    n: int

    def fmt(self, scale: float = 1.0, digits: int = 1, unit: str = "") -> str:
        if self.n == 0:
            return "n/a"
        m, lo, hi = (scale * x for x in (self.mean, self.low, self.high))
        if self.n == 1 or math.isclose(lo, hi):
            return f"{m:,.{digits}f}{unit}"
        return f"{m:,.{digits}f}{unit} [{lo:,.{digits}f}, {hi:,.{digits}f}]"

    def to_json(self) -> dict[str, float | int | None]:
        clean = lambda x: None if not math.isfinite(x) else float(x)  # noqa: E731
        return {"mean": clean(self.mean), "low": clean(self.low), "high": clean(self.high), "n": self.n}


def mean_ci(values: Sequence[float], level: float = 0.95, method: str = "t", *, resamples: int = 10_000,
            seed: int = 0, bounds: tuple[float, float] | None = None) -> Interval:
    """Mean of ``values`` with a two-sided confidence interval.

    ``method="t"``: mean +- t_{df=n-1} * sd / sqrt(n) (the default; exact for
    normal data, conservative enough for 8+ seeds). ``method="bootstrap"``:
    percentile interval of ``resamples`` means of resampled values (fixed
    ``seed``, so the same values give the same interval). ``bounds`` clips the
    interval to the metric's range (a rate stays within [0, 1]). NaNs (a seed
    that delivered nothing has no mean steps) are dropped; ``n`` counts the rest.
    """
    x = np.asarray([v for v in values if v is not None], dtype=np.float64)
    x = x[~np.isnan(x)]
    n = int(x.size)
    if n == 0:
        return Interval(math.nan, math.nan, math.nan, 0)
    mean = float(x.mean())
    if n == 1:
        return Interval(mean, mean, mean, 1)
    if method == "t":
        half = t_quantile(level, n - 1) * float(x.std(ddof=1)) / math.sqrt(n)
        low, high = mean - half, mean + half
    elif method == "bootstrap":
        rng = np.random.default_rng(seed)
        means = x[rng.integers(0, n, size=(resamples, n))].mean(axis=1)
        low, high = (float(q) for q in np.quantile(means, [(1 - level) / 2, (1 + level) / 2]))
    else:
        raise ValueError(f"unknown CI method {method!r}; use 't' or 'bootstrap'")
    if bounds is not None:
        low, high = max(low, bounds[0]), min(high, bounds[1])
    return Interval(mean, low, high, n)


def mean_half_width(values: Sequence[float | None], confidence: float = 0.95) -> tuple[float | None, float | None, int]:
    """``(mean, half-width of the t interval, count)`` of the non-missing values (``None`` where undefined).

    The shape sweep tables use: a symmetric interval, no bounds.
    """
    ci = mean_ci(values, level=confidence)
    if ci.n == 0:
        return None, None, 0
    return ci.mean, (None if ci.n < 2 else (ci.high - ci.low) / 2), ci.n

